#pragma once
// Euclidean distance field for planners: the distance from any point of a window around the map
// to the nearest observed surface, with its gradient and an error bound, from memory reserved at
// init. Each cell of a fixed grid holds the nearest surface point ("site") it knows: seeded at
// sub-voxel precision where the TSDF crosses zero (the cell centre projected onto the surface
// along the gradient), propagated by two sweeps along z with a 2D pass in each slice (vector
// propagation), and read at a query point as the nearest among its cell's 27 sites, each surface
// site standing for the disc of surface around it across its normal. Updates rebuild
// the field in a back buffer, a budgeted number of cells per frame, re-seeding only the chunks
// whose blocks changed, and publish it whole under the MapGuard; queries read the last published
// field. lib/README.md ("Distance field") gives the error bound and the degradation step.

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <limits>
#include <type_traits>

#include <Eigen/Core>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/result.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/map/map_config.hpp"
#include "octofuse/map/octree.hpp"
#include "octofuse/query/free_space.hpp"
#include "octofuse/query/map_guard.hpp"

namespace octofuse {

struct EsdfConfig {
  bool enabled = false;
  // Window of cells_per_side^3 cells (a multiple of 8, 8..1016), each cell_voxels finest voxels
  // on a side (1, 2, 4 or 8). 10 bytes a cell (two buffers of 5).
  int cells_per_side = 128;
  int cell_voxels = 2;
  // World point the window is centred on (clamped into the map's cube); NaN: the cube's centre.
  Eigen::Vector3f centre_W = Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN());
  // Unknown cells count as obstacles (their whole box) when true; then every update re-seeds
  // the whole window, since carving changes what is unknown.
  bool unknown_is_obstacle = false;
  // > 0: the window follows the camera (the pipeline re-centres it on the camera whenever the
  // camera is more than this from the window's centre, m). The next rebuild then builds the new
  // window, copying the seeds of the cells both windows hold where the map did not change there;
  // queries see the old window until it is published. 0: the window stays where centre_W put it.
  float follow_m = 0.0f;
  // Degradation step (8): cells seeded or swept per frame (in whole 8^3 chunks and slices; a
  // rebuild is 3 window volumes). A rebuild that does not finish goes on in the next frames;
  // queries meanwhile see the previous field. 0: no limit (each update finishes in its frame).
  std::uint32_t max_cell_steps = 1u << 18;
};

// ok, or invalid_argument naming nothing (the caller names the setting).
Status validate(const EsdfConfig& config, const MapConfig& map);

struct EsdfAnswer {
  // False: the point lies outside the window, or no surface lies in the 27 cells around it (then
  // lower_bound_m alone says something: the distance to the window's faces inside the cube).
  bool has_distance = false;
  // To the nearest known surface point (or obstacle cell), at most the distance to the window's
  // faces inside the cube (surfaces beyond them are not in the field).
  float distance_m = 0.0f;
  float error_bound_m = 0.0f;  // the nearest observed surface is at least distance - this away
  // max(0, distance - error bound); with no site near, the distance to the window's faces.
  float lower_bound_m = 0.0f;
  // Unit vector away from the nearest surface point (zero without a distance).
  Eigen::Vector3f gradient = Eigen::Vector3f::Zero();
  std::uint64_t map_version = 0;  // the map version the field was built from
};

struct EsdfReport {
  std::uint32_t cell_steps = 0;       // cells seeded or swept this frame
  std::uint32_t chunks_reseeded = 0;  // 8^3-cell chunks seeded from the map this frame
  bool budget_hit = false;            // stopped at max_cell_steps with the rebuild unfinished
  bool published = false;             // a rebuild finished and became the queried field
  bool rebuilding = false;            // a rebuild is in progress after this frame
};

class EsdfField {
 public:
  static constexpr std::size_t kBytesPerCell = 10;  // a cell in each of the two buffers
  static std::size_t bytes_required(const EsdfConfig& config);

  template <typename Arena>
  Status reserve(Arena& arena, const EsdfConfig& config, const MapConfig& map) {
    OCTOFUSE_TRY(validate(config, map));
    const std::size_t cells = cell_count(config.cells_per_side);
    Buffer buffers[2];
    for (Buffer& buffer : buffers) {
      Result<std::uint8_t*> bytes = arena.template allocate_array<std::uint8_t>(kCellBytes * cells);
      OCTOFUSE_TRY(bytes);
      buffer.bytes = bytes.value();
    }
    Result<float*> normals = arena.template allocate_array<float>(3 * kNormalCodes);
    OCTOFUSE_TRY(normals);
    const std::size_t slice_cells =
        static_cast<std::size_t>(config.cells_per_side) * config.cells_per_side;
    Result<float*> slice_cache =
        arena.template allocate_array<float>(2 * kSliceFloats * slice_cells);
    OCTOFUSE_TRY(slice_cache);
    Result<std::uint32_t*> slice_seeds =
        arena.template allocate_array<std::uint32_t>(2 * slice_cells);
    OCTOFUSE_TRY(slice_seeds);
    Result<std::uint8_t*> open_rows = arena.template allocate_array<std::uint8_t>(
        static_cast<std::size_t>(config.cells_per_side));
    OCTOFUSE_TRY(open_rows);
    // The sizing pass hands out no memory to clear.
    if constexpr (!std::is_same<Arena, ArenaSizer>::value) {
      setup(config, map, buffers, normals.value(), slice_cache.value(), slice_seeds.value(),
            open_rows.value());
    }
    return ok_status();
  }
  bool reserved() const { return buffers_[0].bytes != nullptr; }
  const EsdfConfig& config() const { return config_; }

  // Queries hold `guard` shared; updates hold it exclusively to publish. May be null.
  void set_guard(const MapGuard* guard) { guard_ = guard; }

  // Advances the field after frame `frame` changed the map (integration, carving) to
  // `map_version`, within the cell budget. Reads the map without the guard: call it from the
  // thread that writes the map. Allocates nothing.
  template <typename VoxelT>
  EsdfReport update(const Octree<VoxelT>& map, const FreeSpace* free_space, float mu_m,
                    std::uint32_t frame, std::uint64_t map_version);
  // Finishes the rebuild in progress (and starts one when the map changed) without a budget.
  template <typename VoxelT>
  EsdfReport flush(const Octree<VoxelT>& map, const FreeSpace* free_space, float mu_m,
                   std::uint32_t frame, std::uint64_t map_version);
  // The next rebuild seeds every chunk afresh (after eviction removed blocks).
  void mark_all_dirty() { all_dirty_ = true; }
  // The window the next rebuild builds: centred on `centre_W` (clamped into the map's cube, its
  // cells on the map's cell grid). From the thread that updates; a non-finite centre is ignored.
  void centre_on(const Eigen::Vector3f& centre_W);
  // The centre of the window the field is building or has built (centre_on()'s, clamped).
  Eigen::Vector3f target_centre_W() const;
  // Forgets everything (the map was reset). The caller holds the guard exclusively.
  void clear();

  // invalid_argument for a non-finite point.
  Result<EsdfAnswer> distance(const Eigen::Vector3f& p_W) const;
  // `count` points into `out` (holding the guard once); invalid_argument if any is non-finite
  // (those answers stay default).
  Status distances(const Eigen::Vector3f* points_W, std::size_t count, EsdfAnswer* out) const;

  // Window geometry of the published field: its minimum corner (world), cell edge (m), cells per
  // side. With follow_m the corner moves when a rebuild is published (under the guard): read it
  // on the updating thread or holding the guard.
  Eigen::Vector3f window_min_W() const { return windows_[front_].min_W; }
  float cell_m() const { return cell_m_; }
  int cells_per_side() const { return n_; }
  // The bound every answer's distance is within (see lib/README.md).
  float error_bound_m() const { return error_bound_m_; }
  // The map version of the published field (from the mapping thread; readers get it in answers).
  std::uint64_t published_version() const { return published_version_; }

 private:
  // A cell is a 32-bit word and a byte (5 bytes). A seed (kSeedBit) holds its own site: its
  // offset from the cell's minimum corner in 1/site_units_ cells plus kOffsetBias, x in bits 9-16
  // and y in bits 1-8 of the word, z in the byte; kBoxBit; and its normal's 13-bit octahedral
  // code in bits 17-29. A surface site stands for the disc of surface around it (radius
  // kDiscRadius cells) across its normal. Any other cell holds the packed coordinates of the seed
  // whose site it took (10 bits an axis, pack_cell()), or kNoSite.
  // Cells packed 5 bytes apart, so that neighbours share cache lines (a query reads 27).
  static constexpr std::size_t kCellBytes = kBytesPerCell / 2;
  struct Buffer {
    std::uint8_t* bytes = nullptr;
    std::uint32_t word(std::size_t i) const {
      std::uint32_t w;
      std::memcpy(&w, bytes + kCellBytes * i, sizeof w);
      return w;
    }
    void set_word(std::size_t i, std::uint32_t w) const {
      std::memcpy(bytes + kCellBytes * i, &w, sizeof w);
    }
    std::uint8_t site_z(std::size_t i) const { return bytes[kCellBytes * i + 4]; }
    void set_site_z(std::size_t i, std::uint8_t z) const { bytes[kCellBytes * i + 4] = z; }
  };
  static constexpr std::uint32_t kSeedBit = 0x80000000u;
  static constexpr std::uint32_t kBoxBit = 0x40000000u;  // the site is an obstacle cell's centre
  static constexpr std::uint32_t kNoSite = 0x7FFFFFFFu;  // no seed has these coordinates
  static constexpr int kOffsetBias = 96;
  static std::uint32_t pack_cell(int x, int y, int z) {
    return static_cast<std::uint32_t>(x) | (static_cast<std::uint32_t>(y) << 10) |
           (static_cast<std::uint32_t>(z) << 20);
  }
  // The seed a cell's word refers to: its own coordinates for a seed.
  static std::uint32_t seed_of(std::uint32_t word, int x, int y, int z) {
    return (word & kSeedBit) != 0 ? pack_cell(x, y, z) : word;
  }
  std::size_t cell_index(std::uint32_t packed) const {
    const std::size_t n = static_cast<std::size_t>(n_);
    return ((packed >> 20) & 1023u) * n * n + ((packed >> 10) & 1023u) * n + (packed & 1023u);
  }
  // A seed's site, decoded: position in cells from the window's minimum corner.
  struct Site {
    Eigen::Vector3f s = Eigen::Vector3f::Zero();
    int normal = 0;
    bool box = false;
  };
  Site site_of(const Buffer& buffer, std::uint32_t seed) const;
  // A seed's offset from its cell's minimum corner, in site units. Inline: the sweeps decode a
  // seed's own site per cell with it.
  static Eigen::Vector3i seed_offset(std::uint32_t word, std::uint8_t site_z) {
    return Eigen::Vector3i(static_cast<int>((word >> 9) & 255u) - kOffsetBias,
                           static_cast<int>((word >> 1) & 255u) - kOffsetBias,
                           static_cast<int>(site_z) - kOffsetBias);
  }
  // One coordinate of a seed's site, in cells from the window's corner: its cell's and its offset
  // (seed_offset(), `units` a cell).
  static float site_coordinate(int cell, int offset, int units) {
    return static_cast<float>(cell * units + offset) * (1.0f / static_cast<float>(units));
  }
  // The site of the seed at cell (x, y, z) holding `word` and `site_z`.
  Site decode_seed(std::uint32_t word, std::uint8_t site_z, int x, int y, int z) const;
  static constexpr int kNormalSteps = 90;    // octahedral grid per axis
  static constexpr int kNormalCodes = 8192;  // 13 bits; kNoNormal: none
  static constexpr int kNoNormal = kNormalCodes - 1;
  static int encode_normal(const Eigen::Vector3f& n);
  enum class Phase : std::uint8_t { idle, seed, forward, backward };

  // Where a buffer's cells lie in the map, and which of its faces lie inside the cube (beyond
  // them surfaces are not in the field), per axis lo/hi.
  struct Window {
    Eigen::Vector3i min_voxel = Eigen::Vector3i::Zero();
    Eigen::Vector3f min_W = Eigen::Vector3f::Zero();
    bool open_face[3][2] = {{false, false}, {false, false}, {false, false}};
  };
  // The window centred on `centre_W` (NaN on an axis: the cube's middle there).
  Window window_at(const Eigen::Vector3f& centre_W) const;

  static std::size_t cell_count(int n) {
    return static_cast<std::size_t>(n) * static_cast<std::size_t>(n) * static_cast<std::size_t>(n);
  }
  void setup(const EsdfConfig& config, const MapConfig& map, const Buffer (&buffers)[2],
             float* normals, float* slice_cache, std::uint32_t* slice_seeds,
             std::uint8_t* open_rows);
  template <typename VoxelT>
  EsdfReport advance(const Octree<VoxelT>& map, const FreeSpace* free_space, float mu_m,
                     std::uint32_t frame, std::uint64_t map_version, std::uint64_t budget);
  // Seeds the back buffer's chunk: from the map, or (not from_map) copied from the published
  // field where copy_seed() can. True when any cell was seeded from the map.
  template <typename VoxelT>
  bool seed_chunk(const Octree<VoxelT>& map, const FreeSpace* free_space, float mu_m, int chunk,
                  bool from_map);
  template <typename VoxelT>
  bool chunk_changed(const Octree<VoxelT>& map, int chunk) const;
  // A moved window: the seed of back-buffer cell (x, y, z) from the published cell at the same
  // place (`shift_cells` on from it), into `word` and `site_z` (kNoSite where that cell held no
  // seed); false where the published window does not hold the place a margin inside its faces or
  // the shifted site leaves the stored range (the cell is then seeded from the map).
  bool copy_seed(const Eigen::Vector3i& shift_cells, int x, int y, int z, std::uint32_t* word,
                 std::uint8_t* site_z) const;
  void sweep_slice(int z, int dz);
  // Ends the rebuild: its map version becomes the published one, with the back buffer (swap) or
  // with the published field, which a rebuild found to stand for it unchanged.
  void publish(bool swap);
  // Plain distance to the site (a box's less its half diagonal), in cells: what propagation keeps.
  static float propagation_distance(const Site& site, const Eigen::Vector3f& q);
  // The distance to the site's disc (or box), in cells, and the direction away from its nearest
  // point: what queries answer.
  float site_distance(const Site& site, const Eigen::Vector3f& q, Eigen::Vector3f* away) const;
  EsdfAnswer answer_unguarded(const Eigen::Vector3f& p_W) const;

  EsdfConfig config_;
  Buffer buffers_[2];
  const float* normals_ = nullptr;  // unit vector of each normal code (3 floats)
  // A swept slice's cells' sites, decoded (position in cells, what a box's distance is less), and
  // their distances (what propagation compares), kept as cells take nearer sites: each seed is
  // read from where it lies once, not at every comparison. Beside them each cell's seed (packed
  // coordinates, kSeedBit on a seed's own cell, or kNoSite): the sweep works on these and writes
  // the slice's words once at its end. Two slices, the one swept and the one before it along the
  // sweep, whose sites the next slice takes without decoding them again.
  static constexpr std::size_t kSliceFloats = 5;
  float* slice_cache_ = nullptr;
  std::uint32_t* slice_seeds_ = nullptr;
  std::uint8_t* open_rows_ = nullptr;  // per row of the slice swept: 1 where a cell may take a site
  int cached_half_ = 0;                // which half of the slice scratch holds the last swept slice
  int cached_slice_z_ = -1;            // that slice (-1: none)
  int cached_slice_dz_ = 0;            // and its sweep's direction
  int front_ = 0;                      // the published buffer
  int n_ = 0;
  int chunks_per_side_ = 0;
  int cell_voxels_ = 1;
  // Site coordinates per cell: 64, or 32 for cells of one voxel, whose sites may lie further out
  // in cells (the byte of an offset spans 4 cells either way).
  int site_units_ = 64;
  Window windows_[2];  // each buffer's
  Window target_;      // the next rebuild's
  Eigen::Vector3f map_origin_W_ = Eigen::Vector3f::Zero();
  int cube_voxels_ = 0;
  float voxel_m_ = 0.0f;
  float cell_m_ = 0.0f;
  float error_bound_m_ = 0.0f;
  const MapGuard* guard_ = nullptr;

  Phase phase_ = Phase::idle;
  int cursor_ = 0;  // next chunk (seed) or slice (sweeps)
  bool all_dirty_ = true;
  bool rebuild_all_ = true;  // the rebuild in progress seeds every chunk from the map
  std::uint32_t rebuild_chunks_from_map_ = 0;  // chunks it has seeded from the map so far
  bool front_valid_ = false;
  std::uint32_t rebuild_start_frame_ = 0;    // frame the rebuild in progress started at
  std::uint32_t published_start_frame_ = 0;  // frame the published field's rebuild started at
  std::uint64_t rebuild_version_ = 0;        // map version the rebuild in progress reads
  std::uint64_t published_version_ = 0;
  bool have_published_ = false;
};

extern template EsdfReport EsdfField::update(const Octree<TsdfVoxel>&, const FreeSpace*, float,
                                             std::uint32_t, std::uint64_t);
extern template EsdfReport EsdfField::update(const Octree<MultiresVoxel>&, const FreeSpace*, float,
                                             std::uint32_t, std::uint64_t);
extern template EsdfReport EsdfField::update(const Octree<Multires16Voxel>&, const FreeSpace*,
                                             float, std::uint32_t, std::uint64_t);
extern template EsdfReport EsdfField::flush(const Octree<TsdfVoxel>&, const FreeSpace*, float,
                                            std::uint32_t, std::uint64_t);
extern template EsdfReport EsdfField::flush(const Octree<MultiresVoxel>&, const FreeSpace*, float,
                                            std::uint32_t, std::uint64_t);
extern template EsdfReport EsdfField::flush(const Octree<Multires16Voxel>&, const FreeSpace*, float,
                                            std::uint32_t, std::uint64_t);

}  // namespace octofuse
