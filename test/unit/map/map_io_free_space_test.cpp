// Free space in map files: saved and loaded with the map (same nodes, same query answers),
// absent from older saves, and damaged records refused.

#include "octofuse/map/map_io.hpp"

#include <catch2/catch.hpp>

#include "unit/map/map_io_support.hpp"

namespace octofuse {
namespace {

// Answers of point and region queries over a grid through the cube, as bytes (state, distance,
// gradient), with how many points were free and near.
struct QueryAnswers {
  std::vector<std::uint8_t> bytes;
  std::vector<PointAnswer> points;
  int free = 0;
  int near = 0;
};
template <typename VoxelT>
QueryAnswers answers_of(const Octree<VoxelT>& map, const FreeSpace* free_space, float mu_m) {
  const MapQuery<VoxelT> query(map, free_space, mu_m);
  QueryAnswers out;
  auto append = [&](const void* p, std::size_t n) {
    const auto* b = static_cast<const std::uint8_t*>(p);
    out.bytes.insert(out.bytes.end(), b, b + n);
  };
  for (float z = -0.05f; z < 1.8f; z += 0.037f) {
    for (float y = -0.5f; y < 0.4f; y += 0.041f) {
      for (float x = -0.6f; x < 0.6f; x += 0.043f) {
        const Result<PointAnswer> a = query.point(Eigen::Vector3f(x, y, z));
        REQUIRE(a.ok());
        append(&a.value().state, 1);
        append(&a.value().distance_m, 4);
        append(a.value().gradient.data(), 12);
        out.points.push_back(a.value());
        out.free += a.value().state == PointState::free ? 1 : 0;
        out.near += a.value().state == PointState::near ? 1 : 0;
      }
    }
  }
  for (float z = 0.2f; z < 1.6f; z += 0.1f) {
    const Eigen::Vector3f c(0.0f, 0.0f, z);
    const Result<RegionAnswer> box =
        query.box(c - Eigen::Vector3f::Constant(0.1f), c + Eigen::Vector3f::Constant(0.1f));
    const Result<RegionAnswer> swept =
        query.swept_sphere(c, c + Eigen::Vector3f(0.3f, 0.0f, 0.2f), 0.05f);
    REQUIRE((box.ok() && swept.ok()));
    append(&box.value().state, 1);
    append(&swept.value().state, 1);
  }
  return out;
}

TEMPLATE_TEST_CASE("free space is saved and loaded: same nodes, same query answers", "", TsdfVoxel,
                   MultiresVoxel, Multires16Voxel) {
  const PipelineConfig config = config_for<TestType>();
  REQUIRE(config.free_space.enabled);
  const Frames frames(6);
  Mapper<TestType> mapper(config);
  mapper.run(frames, 0, frames.count());
  const FreeSpace& original = mapper.pipeline.free_space();
  REQUIRE(original.node_count() > 50);
  const std::vector<std::uint8_t> file = save(mapper.pipeline.map(), original, 6);

  Mapper<TestType> loaded(config);
  MapFileHeader header;
  ErrorText error;
  for (std::size_t chunk : {std::size_t{1}, std::size_t{13}, std::size_t{1} << 20}) {
    TrickleSource source(file, chunk);
    const Status s =
        load_map(source, loaded.pipeline.map(), &loaded.pipeline.free_space(), &header, &error);
    INFO(error.c_str());
    REQUIRE(s.ok());
  }
  CHECK(header.free_node_count == original.node_count());
  CHECK(header.free_margin_m == original.margin_m());
  CHECK(header.free_octant_voxels == 8);
  CHECK(header.free_max_count == 8);
  CHECK(free_space_bytes(loaded.pipeline.free_space()) == free_space_bytes(original));
  CHECK(save(loaded.pipeline.map(), loaded.pipeline.free_space(), 6) == file);

  // The loaded pipeline answers every query as the saved one, and the grid reaches both the free
  // air in front of the wall and the band around the surfaces.
  const float mu_m = config.fusion.mu_m;
  const QueryAnswers before = answers_of(mapper.pipeline.map(), &original, mu_m);
  const QueryAnswers after = answers_of(loaded.pipeline.map(), &loaded.pipeline.free_space(), mu_m);
  // Only carved free octants answer free (the TSDF's +1 alone is unknown), about 100 of the grid.
  CHECK(before.free > 100);
  CHECK(before.near > 100);
  CHECK(before.free == after.free);
  CHECK(before.bytes == after.bytes);
  // Free space decides many of those answers: without it they are unknown, or free with a
  // smaller distance bound (from the TSDF alone).
  const QueryAnswers tsdf_only = answers_of(mapper.pipeline.map(), nullptr, mu_m);
  int from_free_space = 0;
  for (std::size_t i = 0; i < before.points.size(); ++i) {
    const PointAnswer& a = before.points[i];
    const PointAnswer& b = tsdf_only.points[i];
    from_free_space +=
        a.state == PointState::free && (b.state != PointState::free || b.distance_m != a.distance_m)
            ? 1
            : 0;
  }
  CHECK(from_free_space > 50);

  // A reader that does not keep free space checks its records and skips them.
  BareMap<TestType> bare(config.map);
  REQUIRE(load_bytes(file, bare.map, &error).ok());
  CHECK(save(bare.map, 6) == save(mapper.pipeline.map(), 6));
}

TEST_CASE("a map saved without free space loads, and leaves the free space knowing nothing") {
  const PipelineConfig config = config_for<MultiresVoxel>();
  const Frames frames(3);
  Mapper<MultiresVoxel> mapper(config);
  mapper.run(frames, 0, frames.count());
  REQUIRE(mapper.pipeline.free_space().node_count() > 50);
  const std::vector<std::uint8_t> file = save(mapper.pipeline.map(), 3);
  MapFileHeader header;
  {
    MemorySource source(file.data(), file.size());
    REQUIRE(read_map_header(source).ok());
  }

  // Into a pipeline that already knows free space: it is cleared, not kept from before.
  Mapper<MultiresVoxel> target(config);
  target.run(frames, 0, 2);
  REQUIRE(!empty(target.pipeline.free_space()));
  ErrorText error;
  REQUIRE(
      load_all(file, target.pipeline.map(), target.pipeline.free_space(), &error, &header).ok());
  CHECK(header.free_node_count == 0);
  CHECK(header.free_margin_m == 0.0f);
  CHECK(empty(target.pipeline.free_space()));
  CHECK(save(target.pipeline.map(), 3) == file);
  const QueryAnswers answers =
      answers_of(target.pipeline.map(), &target.pipeline.free_space(), config.fusion.mu_m);
  CHECK(answers.bytes == answers_of(mapper.pipeline.map(), nullptr, config.fusion.mu_m).bytes);

  // A pipeline without free space saves files without it, and loads files with it.
  PipelineConfig off = config;
  off.free_space.enabled = false;
  Mapper<MultiresVoxel> no_free(off);
  no_free.run(frames, 0, frames.count());
  const std::vector<std::uint8_t> with_free =
      save(mapper.pipeline.map(), mapper.pipeline.free_space(), 3);
  REQUIRE(load_bytes(with_free, no_free.pipeline.map(), &error).ok());
  CHECK(save(no_free.pipeline.map(), 3) == file);
  FreeSpace unreserved;
  CHECK(load_all(with_free, no_free.pipeline.map(), unreserved).code() ==
        StatusCode::failed_precondition);
}

TEST_CASE("damaged free-space records are data_loss and leave map and free space empty") {
  const PipelineConfig config = corruption_config();
  Mapper<MultiresVoxel> mapper(config);
  mapper.run(Frames(2), 0, 2);
  const FreeSpace& free_space = mapper.pipeline.free_space();
  const std::uint32_t count = free_space.node_count();
  REQUIRE(count > 20);
  const std::vector<std::uint8_t> file = save(mapper.pipeline.map(), free_space, 2);
  const std::vector<std::size_t> records = record_offsets(file, true);
  REQUIRE(records.back() == file.size());
  const std::size_t free_begin = records[records.size() - 2 - count];
  auto free_at = [&](std::uint32_t i) { return free_begin + i * kFreeRecordBytes; };
  auto child_at = [&](std::uint32_t i, int c) { return free_at(i) + 6 + 4 * c; };
  auto reseal_free = [&](std::vector<std::uint8_t>& f, std::uint32_t i) {
    reseal(f, free_at(i), free_at(i) + kFreeRecordBytes);
  };
  REQUIRE(file[free_at(0)] == 'F');

  Mapper<MultiresVoxel> target(config);
  FreeSpace& loaded = target.pipeline.free_space();
  // Loads `bad` over a full map: it must fail with `code` and `what`, leaving both empty.
  auto expect_refused = [&](const std::vector<std::uint8_t>& bad, StatusCode code,
                            const char* what) {
    REQUIRE(load_all(file, target.pipeline.map(), loaded).ok());
    REQUIRE(!empty(loaded));
    ErrorText error;
    const Status s = load_all(bad, target.pipeline.map(), loaded, &error);
    INFO(error.c_str());
    CHECK(s.code() == code);
    CHECK(std::strstr(error.c_str(), what) != nullptr);
    CHECK(empty(target.pipeline.map()));
    CHECK(empty(loaded));
  };

  SECTION("truncated and flipped bits anywhere in the free-space records") {
    for (std::uint32_t i = 0; i < count; i += 1 + count / 40) {
      for (std::size_t d : {std::size_t{0}, std::size_t{1}, std::size_t{7}, std::size_t{41}}) {
        const std::size_t at = free_at(i) + d;
        expect_refused(std::vector<std::uint8_t>(file.begin(), file.begin() + at),
                       StatusCode::data_loss, "truncated");
        std::vector<std::uint8_t> bad = file;
        bad[at] = static_cast<std::uint8_t>(bad[at] ^ 0x10);
        expect_refused(bad, StatusCode::data_loss, "free-space record");
      }
    }
  }
  SECTION("fields out of range, even with a valid checksum") {
    std::vector<std::uint8_t> bad = file;
    bad[free_at(count - 1) + 1] = 9;  // count above the cap of 8
    reseal_free(bad, count - 1);
    expect_refused(bad, StatusCode::data_loss, "cap");
    bad = file;
    put_u32(bad, free_at(1) + 2, 2);  // frame 2 of a map saved after frames 0 and 1
    reseal_free(bad, 1);
    expect_refused(bad, StatusCode::data_loss, "frame");
    bad = file;
    put_u32(bad, child_at(0, 0), count);  // past the last node
    reseal_free(bad, 0);
    expect_refused(bad, StatusCode::data_loss, "child index out of range");
    std::uint32_t last_parent = 0;
    int last_slot = -1;
    for (std::uint32_t i = 0; i < count; ++i) {
      for (int c = 0; c < 8; ++c) {
        if (free_space.node(i).children[c] == count - 1) {
          last_parent = i;
          last_slot = c;
        }
      }
    }
    REQUIRE(last_slot >= 0);
    bad = file;
    put_u32(bad, child_at(count - 1, 0), last_parent);  // a child before its parent: a cycle
    reseal_free(bad, count - 1);
    expect_refused(bad, StatusCode::data_loss, "child index out of range");
    bad = file;
    bad[free_at(0) + 6 + 4 * 8] = 0x01;  // free sub-cells on the root
    reseal_free(bad, 0);
    expect_refused(bad, StatusCode::data_loss, "sub-cells");
  }
  SECTION("records that do not form one tree") {
    // Parents and levels, from the root.
    std::vector<std::uint32_t> parent(count, FreeSpace::kNoNode);
    std::vector<int> level(count, 0);
    for (std::uint32_t i = 0; i < count; ++i) {
      for (std::uint32_t child : free_space.node(i).children) {
        if (child == FreeSpace::kNoNode) continue;
        REQUIRE(child > i);
        parent[child] = i;
        level[child] = level[i] + 1;
      }
    }
    const std::uint32_t last = count - 1;
    const std::uint32_t p = parent[last];
    REQUIRE(p != FreeSpace::kNoNode);
    int slot = 0;
    while (free_space.node(p).children[slot] != last) ++slot;

    std::vector<std::uint8_t> bad = file;
    put_u32(bad, child_at(p, slot), FreeSpace::kNoNode);  // the last node loses its parent
    reseal_free(bad, p);
    expect_refused(bad, StatusCode::data_loss, "without a parent");

    // The last node also becomes the child of an earlier node with a free slot: two parents.
    std::uint32_t other = FreeSpace::kNoNode;
    int free_slot = -1;
    for (std::uint32_t i = 0; i < last && other == FreeSpace::kNoNode; ++i) {
      for (int c = 0; c < 8; ++c) {
        if (i != p && level[i] < free_space.leaf_level() &&
            free_space.node(i).children[c] == FreeSpace::kNoNode) {
          other = i;
          free_slot = c;
          break;
        }
      }
    }
    REQUIRE(other != FreeSpace::kNoNode);
    bad = file;
    put_u32(bad, child_at(other, free_slot), last);
    reseal_free(bad, other);
    expect_refused(bad, StatusCode::data_loss, "two parents");

    // ... or moves under an earlier node at the finest octant level: below the leaves.
    std::uint32_t leaf = FreeSpace::kNoNode;
    for (std::uint32_t i = 1; i < last; ++i) {
      if (level[i] == free_space.leaf_level()) {
        leaf = i;
        break;
      }
    }
    REQUIRE(leaf != FreeSpace::kNoNode);
    bad = file;
    put_u32(bad, child_at(p, slot), FreeSpace::kNoNode);
    reseal_free(bad, p);
    put_u32(bad, child_at(leaf, 0), last);
    reseal_free(bad, leaf);
    expect_refused(bad, StatusCode::data_loss, "below the finest octant level");
  }
  SECTION("counts and settings in the header") {
    const std::size_t header_end = records[1];
    std::vector<std::uint8_t> bad = file;
    put_u32(bad, kFreeCountAt, count + 1);
    reseal(bad, 0, header_end);
    expect_refused(bad, StatusCode::data_loss, "wrong record tag");
    bad = file;
    put_u32(bad, kFreeCountAt, count - 1);
    reseal(bad, 0, header_end);
    expect_refused(bad, StatusCode::data_loss, "");
    for (std::size_t at : {kFreeOctantAt, kFreeCapAt}) {
      bad = file;
      bad[at] = at == kFreeOctantAt ? 3 : 0;
      reseal(bad, 0, header_end);
      expect_refused(bad, StatusCode::data_loss,
                     at == kFreeOctantAt ? "free-space octants of 3 voxels" : "count cap 0");
    }
    const float bad_margins[] = {std::numeric_limits<float>::quiet_NaN(), -0.01f, 0.0f};
    for (float margin : bad_margins) {
      std::uint32_t bits;
      std::memcpy(&bits, &margin, 4);
      bad = file;
      put_u32(bad, kFreeMarginAt, bits);
      reseal(bad, 0, header_end);
      expect_refused(bad, StatusCode::data_loss, "free-space margin");
    }
    bad = file;
    put_u32(bad, records[records.size() - 2] + 9, count - 1);  // the end record's free count
    reseal(bad, records[records.size() - 2], records.back());
    expect_refused(bad, StatusCode::data_loss, "end record");
  }
  SECTION("other settings or a smaller pool than the file's") {
    PipelineConfig wider = config;
    wider.free_space.margin_m = 2.0f * config.map.voxel_size_m;
    Mapper<MultiresVoxel> other(wider);
    ErrorText error;
    CHECK(load_all(file, other.pipeline.map(), other.pipeline.free_space(), &error).code() ==
          StatusCode::invalid_argument);
    CHECK(std::string(error.c_str()).find("margin") != std::string::npos);
    CHECK(empty(other.pipeline.map()));
    CHECK(empty(other.pipeline.free_space()));
    PipelineConfig finer = config;
    finer.free_space.finest_octant_voxels = 4;
    Mapper<MultiresVoxel> finer_mapper(finer);
    CHECK(load_all(file, finer_mapper.pipeline.map(), finer_mapper.pipeline.free_space()).code() ==
          StatusCode::invalid_argument);
    PipelineConfig small = config;
    small.free_space.node_capacity = count - 1;
    Mapper<MultiresVoxel> small_mapper(small);
    CHECK(load_all(file, small_mapper.pipeline.map(), small_mapper.pipeline.free_space(), &error)
              .code() == StatusCode::resource_exhausted);
    CHECK(std::string(error.c_str()).find("free-space nodes") != std::string::npos);
    CHECK(empty(small_mapper.pipeline.map()));
    CHECK(empty(small_mapper.pipeline.free_space()));
  }
  SECTION("saving refuses free space that the loader would refuse") {
    VectorSink sink;
    MapSaveInfo info;
    info.mu_m = 0.16f;
    info.frames = 1;  // frame 1 was carved too
    CHECK(save_map(mapper.pipeline.map(), &free_space, info, sink).code() ==
          StatusCode::invalid_argument);
    FreeSpace unreserved;
    info.frames = 2;
    CHECK(save_map(mapper.pipeline.map(), &unreserved, info, sink).code() ==
          StatusCode::failed_precondition);
  }
}

}  // namespace
}  // namespace octofuse
