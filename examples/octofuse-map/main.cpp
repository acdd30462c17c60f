// octofuse-map: looks into a saved map (octofuse-replay --save-map) or a block store
// (--map-file). `info FILE` checks the whole file and prints its format version, voxel type and
// size, blocks per scale, free-space nodes and memory; `mesh FILE OUT.ply` meshes it as
// octofuse-replay's mesh.ply. A store holds the blocks a run evicted (after a crash, what it had
// not saved otherwise); it is read without being changed. `compare A.ply B.ply` measures how far
// each mesh's vertices lie from the other's surface (a capped run against an uncapped one, a
// build against the one before).

#include <sys/stat.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "cli.hpp"
#include "host_memory.hpp"
#include "mesh_distance.hpp"
#include "octofuse/map/coarse_estimate.hpp"
#include "octofuse/mesh/mesher.hpp"
#include "octofuse/ports/host/block_store_file.hpp"
#include "octofuse/ports/host/map_file.hpp"
#include "octofuse/ports/host/ply.hpp"
#include "octofuse/query/free_space.hpp"
#include "runner.hpp"

namespace octofuse {
namespace {

// The commands and the one option, each with its usage text.
struct Command {
  const char* name;
  const char* arguments;
  const char* help;
};
const Command kCommands[] = {
    {"info", "FILE",
     "check FILE whole and print its format version, voxel type and size,\n"
     "cube, blocks per scale, free-space nodes and the memory they take;\n"
     "FILE is a map file (--save-map) or a block store (--map-file)"},
    {"mesh", "FILE OUT.ply",
     "write FILE's surface (a map file or a block store) as a binary PLY\n"
     "(as octofuse-replay's mesh.ply)"},
    {"compare", "A.ply B.ply",
     "how far each mesh's vertices lie from the other's surface: the share\n"
     "within M and 2 M (--within, default 0.01 m), the median, p90 and p99\n"
     "distance, and the share farther than 4 M (where the search stops)"},
};

struct MeshArgs {
  MeshReadScale read_scale = MeshReadScale::current;
};
const cli::Option<MeshArgs> kMeshOptions[] = {
    {"--mesh-scale", "S",
     "mesh at each block's current scale (current, the default) or at the\n"
     "finest scale it was fused at (finest)",
     [](MeshArgs& a, const std::string& v) {
       if (!examples::parse_mesh_read_scale(v, &a.read_scale)) {
         return std::string("--mesh-scale must be current or finest");
       }
       return std::string();
     }},
};

void print_usage() {
  std::string text =
      "usage: octofuse-map info FILE\n"
      "       octofuse-map mesh FILE OUT.ply [--mesh-scale current|finest]\n"
      "       octofuse-map compare A.ply B.ply [--within M]\n"
      "\n";
  for (const Command& command : kCommands) {
    text += cli::format_option(command.name, command.arguments, command.help);
  }
  text += cli::options_usage(kMeshOptions);
  text += cli::format_option("--within", "M", "compare's distance in metres, in [1e-5, 10]");
  std::fputs(text.c_str(), stdout);
}

int error_exit(const std::string& message) {
  std::fprintf(stderr, "error: %s\n", message.c_str());
  return 1;
}

using examples::VectorMeshSink;
// Heap memory for a map exactly as large as the file needs.
using MapBuffer = examples::AlignedBuffer;

// Blocks per current scale, and never fused.
template <typename VoxelT>
void print_blocks(const Octree<VoxelT>& map) {
  std::uint32_t per_scale[kMaxBlockScale + 1] = {};
  std::uint32_t never = 0;
  map.for_each_block([&](const VoxelBlock<VoxelT>& b) {
    if (b.integrated()) {
      ++per_scale[b.current_scale];
    } else {
      ++never;
    }
  });
  const MapMemory memory = map.memory();
  std::printf("inner nodes     %u\n", memory.nodes_used);
  std::printf("blocks          %u\n", memory.blocks_used);
  for (int s = 0; s <= kMaxBlockScale; ++s) {
    std::printf("  at scale %d     %u\n", s, per_scale[s]);
  }
  std::printf("  never fused   %u\n", never);
  if (Octree<VoxelT>::kSplitFinest) {
    std::printf("finest levels   %u\n", memory.finest_used);
    std::printf("mid levels      %u\n", memory.mid_used);
  }
  // What allocating blocks at coarser octree levels would keep (coarse_estimate.hpp).
  std::vector<std::uint64_t> scratch(map.block_count());
  const Result<CoarseEstimate> coarse = estimate_coarse_blocks(map, scratch.data(), scratch.size());
  if (!coarse.ok()) return;
  const CoarseEstimate& c = coarse.value();
  for (int up = kMaxBlockScale; up >= 1; --up) {
    std::printf("coarse %d up     %llu blocks never fused finer than scale %d, in %llu octants\n",
                up, static_cast<unsigned long long>(c.replaced[up - 1]), up,
                static_cast<unsigned long long>(c.octants[up - 1]));
  }
  std::printf("coarse blocks   %llu would hold the %llu fused blocks\n",
              static_cast<unsigned long long>(c.blocks_after()),
              static_cast<unsigned long long>(c.fused_blocks));
}

template <typename VoxelT>
int write_mesh(const Octree<VoxelT>& map, const char* out_path, MeshReadScale read_scale) {
  MeshConfig mesh_config;
  mesh_config.read_scale = read_scale;
  mesh_config.vertex_capacity = static_cast<std::uint32_t>(
      std::clamp<std::uint64_t>(std::uint64_t{96} * map.block_count(), 1u << 16, 1u << 23));
  const std::size_t mesh_bytes = Mesher<VoxelT>::bytes_required(mesh_config);
  MapBuffer mesh_buffer(mesh_bytes);
  LinearArena mesh_arena(mesh_buffer.data, mesh_bytes);
  Mesher<VoxelT> mesher;
  if (mesh_buffer.data == nullptr || !mesher.reserve(mesh_arena, mesh_config).ok()) {
    return error_exit("cannot reserve the mesher");
  }
  VectorMeshSink sink;
  const Result<MeshStats> meshed = mesher.extract(map, sink);
  if (!meshed.ok()) {
    std::fprintf(stderr, "warning: meshing stopped early (%s)\n", meshed.status().name());
  }
  host::MeshView mesh;
  mesh.vertices = sink.positions.data();
  mesh.vertex_count = sink.positions.size();
  mesh.indices = sink.indices.data();
  mesh.triangle_count = sink.indices.size() / 3;
  mesh.vertex_scale = sink.scales.data();
  ErrorText ply_error;
  if (!host::write_ply(out_path, mesh, &ply_error).ok()) return error_exit(ply_error.c_str());
  std::printf("wrote %s (%zu vertices, %zu triangles)\n", out_path, mesh.vertex_count,
              mesh.triangle_count);
  return 0;
}

void print_distances(const std::string& from, const std::string& to,
                     const examples::SurfaceDistances& d, float within_m, float search_m) {
  const double n = static_cast<double>(d.points);
  std::printf(
      "%s's vertices to %s's surface: %.1f %% within %g m, %.1f %% within %g m; median %.2f mm, "
      "p90 %.2f mm, p99 %.2f mm; %.1f %% farther than %g m\n",
      from.c_str(), to.c_str(), 100.0 * static_cast<double>(d.within) / n,
      static_cast<double>(within_m), 100.0 * static_cast<double>(d.within_twice) / n,
      2.0 * static_cast<double>(within_m), 1e3 * d.median_m, 1e3 * d.p90_m, 1e3 * d.p99_m,
      100.0 * static_cast<double>(d.beyond) / n, static_cast<double>(search_m));
}

// Both ways: A's vertices against B's triangles, then B's against A's.
int compare_meshes(const char* path_a, const char* path_b, float within_m) {
  host::Mesh mesh[2];
  const char* paths[2] = {path_a, path_b};
  for (int i = 0; i < 2; ++i) {
    ErrorText error;
    if (!host::read_ply(paths[i], &mesh[i], &error).ok()) return error_exit(error.c_str());
    if (mesh[i].indices.empty()) return error_exit(std::string(paths[i]) + ": no triangles");
    std::printf("%s: %zu vertices, %zu triangles\n", paths[i], mesh[i].vertices.size(),
                mesh[i].indices.size() / 3);
  }
  const float search_m = examples::kCompareSearchWithins * within_m;
  examples::MeshRef refs[2];
  for (int i = 0; i < 2; ++i) {
    refs[i] = {mesh[i].vertices.data(), mesh[i].vertices.size(), mesh[i].indices.data(),
               mesh[i].indices.size() / 3};
  }
  examples::SurfaceDistances d[2];
  const int refused = examples::compare_meshes(refs[0], refs[1], within_m, &d[0], &d[1]);
  if (refused >= 0) {
    return error_exit(std::string(paths[refused]) +
                      ": a vertex is not finite or a triangle spans more than 4096 cells of " +
                      std::to_string(search_m) + " m");
  }
  for (int i = 0; i < 2; ++i) print_distances(paths[i], paths[1 - i], d[i], within_m, search_m);
  return 0;
}

// Opens a store kept beside block store `path` (FILE.fine, FILE.free) read only (a torn tail is
// warned about) and checks it was made for the same map (its geometry bytes `expected`): false,
// with the reason in `error`, otherwise.
bool open_side_store(host::BlockStoreFile& store, const std::string& side_path,
                     const std::uint8_t* expected, std::size_t expected_size, const char* what,
                     const char* path, ErrorText* error) {
  ErrorText warning;
  if (!store.open(side_path.c_str(), nullptr, 0, error, &warning).ok()) return false;
  if (!warning.empty()) std::fprintf(stderr, "warning: %s\n", warning.c_str());
  if (store.geometry_size() != expected_size ||
      std::memcmp(store.geometry(), expected, expected_size) != 0) {
    error->set("%s: not %s of %s", side_path.c_str(), what, path);
    return false;
  }
  return true;
}

// A block store: its blocks merged into one map (on the heap), then as for a map file.
template <typename VoxelT>
int run_store(const std::string& command, const char* path, host::BlockStoreFile& store,
              const host::StoreGeometry& geometry, const char* out_path, MeshReadScale read_scale) {
  MapConfig config;
  config.voxel_size_m = geometry.voxel_size_m;
  config.voxel_depth = geometry.voxel_depth;
  config.origin_W = geometry.origin_W;
  std::unique_ptr<host::HeapMap<VoxelT>> merged;
  ErrorText error;
  // Finest levels the run gave up for room lie beside the store, in FILE.fine: merged too (each
  // at its block's scale; the default weight cap only bounds their weights).
  const std::string finest_path = std::string(path) + ".fine";
  host::BlockStoreFile finest_store;
  host::FinestMerge finest;
  if (host::is_block_store_file(finest_path.c_str())) {
    std::uint8_t expected[host::kFinestStoreGeometryBytes];
    host::encode_finest_store_geometry(geometry, expected);
    if (!open_side_store(finest_store, finest_path, expected, sizeof(expected),
                         "the finest-level store", path, &error)) {
      return error_exit(error.c_str());
    }
    finest.store = &finest_store;
  }
  if (!host::merge_map_with_store<VoxelT>(nullptr, config, store, path, &merged, &error, finest)
           .ok()) {
    return error_exit(error.c_str());
  }
  const Octree<VoxelT>& map = merged->map;
  if (command != "info") return write_mesh(map, out_path, read_scale);
  const host::BlockStoreFileStats stats = store.stats();
  std::printf("file            %s (%llu bytes, a block store, every record checked)\n", path,
              static_cast<unsigned long long>(stats.file_bytes + stats.dropped_bytes));
  std::printf("records         %llu, of %llu blocks (%llu bytes of newest records)\n",
              static_cast<unsigned long long>(stats.entries),
              static_cast<unsigned long long>(stats.keys),
              static_cast<unsigned long long>(stats.live_bytes));
  std::printf("voxel type      %s\n", map_voxel_type_name(geometry.voxel_type));
  std::printf("voxel size      %g m\n", static_cast<double>(geometry.voxel_size_m));
  std::printf(
      "cube            %d voxels per side (%g m), origin %g %g %g m\n", 1 << geometry.voxel_depth,
      static_cast<double>(geometry.voxel_size_m) * (1 << geometry.voxel_depth),
      static_cast<double>(geometry.origin_W.x()), static_cast<double>(geometry.origin_W.y()),
      static_cast<double>(geometry.origin_W.z()));
  print_blocks(map);
  if (finest.store != nullptr) {
    std::printf("finest levels   %llu records in %s (merged)\n",
                static_cast<unsigned long long>(finest_store.stats().keys), finest_path.c_str());
  } else {
    std::printf("finest levels   not stored\n");
  }
  // The free space a run forgot lies beside the store, in FILE.free (by region).
  const std::string free_path = std::string(path) + ".free";
  if (!host::is_block_store_file(free_path.c_str())) {
    std::printf("free space      not stored\n");
  } else {
    host::BlockStoreFile free_store;
    std::uint8_t expected[host::kFreeStoreGeometryBytes];
    host::encode_free_store_geometry(geometry, expected);
    if (!open_side_store(free_store, free_path, expected, sizeof(expected), "the free space", path,
                         &error)) {
      return error_exit(error.c_str());
    }
    // Every region grafted into an empty tree: each is checked, and the nodes counted.
    FreeSpaceConfig free_config;
    free_config.node_capacity = 1;
    const std::size_t free_bytes = FreeSpace::bytes_required(free_config, config, 1, 1);
    if (free_bytes == 0) return error_exit(free_path + ": cannot size its free space");
    MapBuffer free_buffer(free_bytes);
    if (free_buffer.data == nullptr) return error_exit("cannot reserve the free-space memory");
    LinearArena free_arena(free_buffer.data, free_bytes);
    FreeSpace empty;
    if (!empty.reserve(free_arena, free_config, config, 1, 1).ok()) {
      return error_exit("cannot reserve the free space");
    }
    std::unique_ptr<host::HeapFreeSpace> merged_free;
    if (!host::merge_free_space_with_store(empty, free_store, free_path.c_str(), &merged_free,
                                           &error)
             .ok()) {
      return error_exit(error.c_str());
    }
    std::printf(
        "free space      %u nodes, %zu bytes, from %llu stored regions in %s (each "
        "checked)\n",
        merged_free->space.node_count(), merged_free->space.bytes_used(),
        static_cast<unsigned long long>(free_store.stats().keys), free_path.c_str());
  }
  std::printf("memory          %.2f MB (blocks, finest and mid levels, nodes)\n",
              static_cast<double>(map.memory().bytes_used) / 1048576.0);
  return 0;
}

template <typename VoxelT>
int run(const std::string& command, const char* path, const MapFileHeader& header,
        const char* out_path, MeshReadScale read_scale) {
  const MapConfig config = map_config_for(header);
  const std::size_t bytes = Octree<VoxelT>::bytes_required(config);
  if (bytes == 0) return error_exit(std::string(path) + ": cannot size a map for it");
  MapBuffer buffer(bytes);
  if (buffer.data == nullptr) return error_exit("cannot reserve the map memory");
  LinearArena arena(buffer.data, bytes);
  Octree<VoxelT> map;
  if (!map.reserve(arena, config).ok()) return error_exit("cannot reserve the map");
  // info checks the free space as a tree too (it needs a pool for that); mesh only skips it.
  FreeSpace free_space;
  std::unique_ptr<MapBuffer> free_buffer;
  if (command == "info" && header.free_node_count > 0) {
    FreeSpaceConfig free_config;
    free_config.node_capacity = header.free_node_count;
    free_config.margin_m = header.free_margin_m;
    free_config.finest_octant_voxels = header.free_octant_voxels;
    free_config.max_free_count = static_cast<std::uint8_t>(header.free_max_count);
    const std::size_t free_bytes = FreeSpace::bytes_required(free_config, config, 1, 1);
    if (free_bytes == 0) return error_exit(std::string(path) + ": cannot size its free space");
    free_buffer = std::make_unique<MapBuffer>(free_bytes);
    if (free_buffer->data == nullptr) return error_exit("cannot reserve the free-space memory");
    LinearArena free_arena(free_buffer->data, free_bytes);
    if (!free_space.reserve(free_arena, free_config, config, 1, 1).ok()) {
      return error_exit("cannot reserve the free space");
    }
  }
  ErrorText error;
  if (!host::load_map_file(path, map, free_space.reserved() ? &free_space : nullptr, nullptr,
                           &error)
           .ok()) {
    return error_exit(error.c_str());
  }

  if (command == "info") {
    const MapMemory memory = map.memory();
    struct stat st;
    const long long file_bytes = ::stat(path, &st) == 0 ? static_cast<long long>(st.st_size) : -1;
    std::printf("file            %s (%lld bytes, every record checked)\n", path, file_bytes);
    std::printf("format version  %u\n", static_cast<unsigned>(header.version));
    std::printf("voxel type      %s\n", map_voxel_type_name(header.voxel_type));
    std::printf("voxel size      %g m\n", static_cast<double>(header.voxel_size_m));
    std::printf("mu              %g m (truncation distance it was fused with)\n",
                static_cast<double>(header.mu_m));
    std::printf("cube            %d voxels per side (%g m), origin %g %g %g m\n",
                1 << header.voxel_depth,
                static_cast<double>(header.voxel_size_m) * (1 << header.voxel_depth),
                static_cast<double>(header.origin_W.x()), static_cast<double>(header.origin_W.y()),
                static_cast<double>(header.origin_W.z()));
    std::printf("frames          %llu\n", static_cast<unsigned long long>(header.frames));
    print_blocks(map);
    if (free_space.reserved()) {
      std::printf(
          "free space      %u nodes, %zu bytes (octants of %d voxels and up, margin %g m)\n",
          free_space.node_count(), free_space.bytes_used(), header.free_octant_voxels,
          static_cast<double>(header.free_margin_m));
    } else {
      std::printf("free space      not saved\n");
    }
    std::printf("memory          %.2f MB (blocks, finest and mid levels, nodes)\n",
                static_cast<double>(memory.bytes_used) / 1048576.0);
    return 0;
  }

  return write_mesh(map, out_path, read_scale);
}

}  // namespace
}  // namespace octofuse

int main(int argc, char** argv) {
  using namespace octofuse;
  if (argc >= 2 && (std::string(argv[1]) == "-h" || std::string(argv[1]) == "--help")) {
    print_usage();
    return 0;
  }
  if (argc < 3) {
    std::fprintf(stderr, "error: expected a command and a map file (see --help)\n");
    return 2;
  }
  const std::string command = argv[1];
  const char* path = argv[2];
  const char* out_path = nullptr;
  MeshReadScale read_scale = MeshReadScale::current;
  if (command == "info") {
    if (argc != 3) {
      std::fprintf(stderr, "error: info takes one map file\n");
      return 2;
    }
  } else if (command == "mesh") {
    if (argc != 4 && !(argc == 6 && std::string(argv[4]) == "--mesh-scale")) {
      std::fprintf(stderr, "error: mesh takes a map file and an output .ply (see --help)\n");
      return 2;
    }
    out_path = argv[3];
    MeshArgs mesh_args;
    std::string error;
    if (cli::parse_options(argc, argv, 4, kMeshOptions, "unknown option ", &mesh_args, &error) !=
        cli::Parsed::options) {
      return cli::fail(error);
    }
    read_scale = mesh_args.read_scale;
  } else if (command == "compare") {
    float within_m = 0.01f;
    if (argc == 6 && std::string(argv[4]) == "--within") {
      double value = 0.0;
      if (!cli::parse_double(argv[5], 1e-5, 10.0, value)) {
        return cli::fail("--within needs metres in [1e-5, 10]");
      }
      within_m = static_cast<float>(value);
    } else if (argc != 4) {
      std::fprintf(stderr, "error: compare takes two .ply meshes [--within M] (see --help)\n");
      return 2;
    }
    return compare_meshes(argv[2], argv[3], within_m);
  } else {
    std::fprintf(stderr, "error: unknown command '%s' (info, mesh or compare)\n", command.c_str());
    return 2;
  }
  ErrorText error;
  if (host::is_block_store_file(path)) {
    host::BlockStoreFile store;
    ErrorText warning;
    if (!store.open(path, nullptr, 0, &error, &warning).ok()) {
      std::fprintf(stderr, "error: %s\n", error.c_str());
      return 1;
    }
    if (!warning.empty()) std::fprintf(stderr, "warning: %s\n", warning.c_str());
    host::StoreGeometry geometry;
    // The stores kept beside a block store: the block store's geometry with a tag after it.
    static_assert(host::kFreeStoreGeometryBytes == host::kStoreGeometryBytes + 1 &&
                      host::kFinestStoreGeometryBytes == host::kStoreGeometryBytes + 1,
                  "a side store's geometry is the block store's and one tag byte");
    struct SideStore {
      std::uint8_t tag;
      const char* what;
      const char* suffix;
    };
    for (const SideStore& side :
         {SideStore{host::kFreeStoreGeometryTag, "a free-space store", ".free"},
          SideStore{host::kFinestStoreGeometryTag, "a finest-level store", ".fine"}}) {
      if (store.geometry_size() == host::kStoreGeometryBytes + 1 &&
          store.geometry()[host::kStoreGeometryBytes] == side.tag) {
        std::fprintf(stderr,
                     "error: %s: %s; give its block store (the name without \"%s\"), which reads "
                     "it too\n",
                     path, side.what, side.suffix);
        return 1;
      }
    }
    if (!host::decode_store_geometry(store.geometry(), store.geometry_size(), &geometry)) {
      std::fprintf(stderr, "error: %s: the store's map geometry is out of range\n", path);
      return 1;
    }
    if (geometry.voxel_type == MapVoxelType::multires) {
      return run_store<MultiresVoxel>(command, path, store, geometry, out_path, read_scale);
    }
    if (geometry.voxel_type == MapVoxelType::multires16) {
      return run_store<Multires16Voxel>(command, path, store, geometry, out_path, read_scale);
    }
    return run_store<TsdfVoxel>(command, path, store, geometry, out_path, read_scale);
  }
  const Result<MapFileHeader> header = host::read_map_file_header(path, &error);
  if (!header.ok()) {
    std::fprintf(stderr, "error: %s\n", error.c_str());
    return 1;
  }
  if (header.value().voxel_type == MapVoxelType::multires) {
    return run<MultiresVoxel>(command, path, header.value(), out_path, read_scale);
  }
  if (header.value().voxel_type == MapVoxelType::multires16) {
    return run<Multires16Voxel>(command, path, header.value(), out_path, read_scale);
  }
  return run<TsdfVoxel>(command, path, header.value(), out_path, read_scale);
}
