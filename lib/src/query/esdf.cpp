#include "octofuse/query/esdf.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "octofuse/map/interpolation.hpp"

namespace octofuse {

namespace {
constexpr int kCopyMarginCells = 2;          // see copy_seed()
constexpr float kHalfDiagonal = 0.8660254f;  // sqrt(3) / 2, in cells
// Surface sites lie about a cell apart on the surface, so every surface point lies within half a
// face diagonal of one: each site stands for the disc of that radius around it.
constexpr float kDiscRadius = 0.70710678f;
constexpr int kChunkCells = 8;
// How far, in reaches (half a cell diagonal and a voxel), a cell looks for a thin part's dip.
constexpr float kValleyReach = 2.0f;
constexpr int kValleyBisections = 4;
constexpr float kValleyRise = 0.2f;  // least slope beyond a dip's bottom (as the seeding's)

bool finite(const Eigen::Vector3f& v) {
  return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z());
}

// A site coordinate in whole units (`units` a cell), inside the window.
int to_site_units(float cells, int n, int units) {
  const float unit = static_cast<float>(units);
  const float at = std::floor(cells * unit + 0.5f);
  const float top = static_cast<float>(n) * unit - 1.0f;
  return static_cast<int>(at < 0.0f ? 0.0f : at > top ? top : at);
}

// A seed's offset from its cell's corner (`corner` in units), biased into a byte.
std::uint32_t offset_byte(int units, int corner, int bias) {
  return static_cast<std::uint32_t>(std::min(std::max(units - corner + bias, 0), 255));
}
}  // namespace

Status validate(const EsdfConfig& config, const MapConfig& map) {
  const int n = config.cells_per_side;
  const int c = config.cell_voxels;
  if (n < 8 || n > 1016 || n % kChunkCells != 0) return Status(StatusCode::invalid_argument);
  if (c != 1 && c != 2 && c != 4 && c != 8) return Status(StatusCode::invalid_argument);
  if (static_cast<long>(n) * c > static_cast<long>(map.voxels_per_side())) {
    return Status(StatusCode::invalid_argument);
  }
  // The buffers must be addressable: a 32-bit target cannot hold the largest windows (1016^3
  // cells take 10.5 GB), and their byte counts would wrap.
  const std::uint64_t cells =
      static_cast<std::uint64_t>(n) * static_cast<std::uint64_t>(n) * static_cast<std::uint64_t>(n);
  if (cells * EsdfField::kBytesPerCell > std::numeric_limits<std::size_t>::max() / 2) {
    return Status(StatusCode::invalid_argument);
  }
  const Eigen::Vector3f& centre = config.centre_W;
  const bool all_nan = std::isnan(centre.x()) && std::isnan(centre.y()) && std::isnan(centre.z());
  if (!all_nan && !finite(centre)) return Status(StatusCode::invalid_argument);
  if (!std::isfinite(config.follow_m) || config.follow_m < 0.0f) {
    return Status(StatusCode::invalid_argument);
  }
  return ok_status();
}

std::size_t EsdfField::bytes_required(const EsdfConfig& config) {
  const std::size_t cells = cell_count(config.cells_per_side);
  const std::size_t slice_cells =
      static_cast<std::size_t>(config.cells_per_side) * config.cells_per_side;
  return 2 * cells * kCellBytes + 3 * kNormalCodes * sizeof(float) + alignof(float) +
         2 * kSliceFloats * slice_cells * sizeof(float) + alignof(float) +
         2 * slice_cells * sizeof(std::uint32_t) + alignof(std::uint32_t) +
         static_cast<std::size_t>(config.cells_per_side);
}

// Octahedral code of a direction (sign ignored by the disc distance, kept anyway).
int EsdfField::encode_normal(const Eigen::Vector3f& n) {
  const float l1 = std::abs(n.x()) + std::abs(n.y()) + std::abs(n.z());
  if (!(l1 > 0.0f)) return kNoNormal;
  float u = n.x() / l1;
  float v = n.y() / l1;
  if (n.z() < 0.0f) {
    const float fu = (1.0f - std::abs(v)) * (u >= 0.0f ? 1.0f : -1.0f);
    const float fv = (1.0f - std::abs(u)) * (v >= 0.0f ? 1.0f : -1.0f);
    u = fu;
    v = fv;
  }
  const float top = static_cast<float>(kNormalSteps - 1);
  const int i = static_cast<int>(std::floor((u + 1.0f) * 0.5f * top + 0.5f));
  const int j = static_cast<int>(std::floor((v + 1.0f) * 0.5f * top + 0.5f));
  return std::min(std::max(i, 0), kNormalSteps - 1) * kNormalSteps +
         std::min(std::max(j, 0), kNormalSteps - 1);
}

void EsdfField::setup(const EsdfConfig& config, const MapConfig& map, const Buffer (&buffers)[2],
                      float* normals, float* slice_cache, std::uint32_t* slice_seeds,
                      std::uint8_t* open_rows) {
  slice_cache_ = slice_cache;
  slice_seeds_ = slice_seeds;
  open_rows_ = open_rows;
  config_ = config;
  buffers_[0] = buffers[0];
  buffers_[1] = buffers[1];
  const float top = static_cast<float>(kNormalSteps - 1);
  for (int code = 0; code < kNormalCodes; ++code) {
    Eigen::Vector3f n(0.0f, 0.0f, 1.0f);
    if (code < kNormalSteps * kNormalSteps) {
      const float u = static_cast<float>(code / kNormalSteps) / top * 2.0f - 1.0f;
      const float v = static_cast<float>(code % kNormalSteps) / top * 2.0f - 1.0f;
      n = Eigen::Vector3f(u, v, 1.0f - std::abs(u) - std::abs(v));
      if (n.z() < 0.0f) {
        n.x() = (1.0f - std::abs(v)) * (u >= 0.0f ? 1.0f : -1.0f);
        n.y() = (1.0f - std::abs(u)) * (v >= 0.0f ? 1.0f : -1.0f);
      }
      n.normalize();
    }
    for (int k = 0; k < 3; ++k) normals[3 * code + k] = n[k];
  }
  normals_ = normals;
  n_ = config.cells_per_side;
  chunks_per_side_ = n_ / kChunkCells;
  cell_voxels_ = config.cell_voxels;
  site_units_ = cell_voxels_ == 1 ? 32 : 64;
  voxel_m_ = map.voxel_size_m;
  cell_m_ = voxel_m_ * static_cast<float>(cell_voxels_);
  // A site lies within a cell diagonal of the nearest surface point (both in one cell), and the
  // TSDF places the surface within about a finest voxel.
  error_bound_m_ = 2.0f * kHalfDiagonal * cell_m_ + voxel_m_;
  map_origin_W_ = map.origin_W;
  cube_voxels_ = map.voxels_per_side();
  target_ = window_at(config.centre_W);
  windows_[0] = windows_[1] = target_;
  clear();
}

EsdfField::Window EsdfField::window_at(const Eigen::Vector3f& centre_W) const {
  Window w;
  const int side = n_ * cell_voxels_;
  for (int a = 0; a < 3; ++a) {
    int lo = (cube_voxels_ - side) / 2;
    if (!std::isnan(centre_W[a])) {
      const float centre_voxels = (centre_W[a] - map_origin_W_[a]) / voxel_m_;
      const float start = centre_voxels - 0.5f * static_cast<float>(side);
      const float clamped =
          std::max(0.0f, std::min(static_cast<float>(cube_voxels_ - side), std::floor(start)));
      lo = static_cast<int>(clamped);
    }
    lo -= lo % cell_voxels_;  // cells on the map's cell grid
    w.min_voxel[a] = lo;
    w.min_W[a] = map_origin_W_[a] + static_cast<float>(lo) * voxel_m_;
    w.open_face[a][0] = lo > 0;
    w.open_face[a][1] = lo + side < cube_voxels_;
  }
  return w;
}

void EsdfField::centre_on(const Eigen::Vector3f& centre_W) {
  if (!reserved() || !finite(centre_W)) return;
  target_ = window_at(centre_W);
}

Eigen::Vector3f EsdfField::target_centre_W() const {
  return target_.min_W + Eigen::Vector3f::Constant(0.5f * static_cast<float>(n_) * cell_m_);
}

void EsdfField::clear() {
  const std::size_t cells = cell_count(n_);
  for (int b = 0; b < 2; ++b) {
    for (std::size_t i = 0; i < cells; ++i) {
      buffers_[b].set_word(i, kNoSite);
      buffers_[b].set_site_z(i, 0);
    }
  }
  phase_ = Phase::idle;
  cursor_ = 0;
  cached_slice_z_ = -1;
  all_dirty_ = true;
  rebuild_all_ = true;
  front_valid_ = false;
  have_published_ = false;
  rebuild_start_frame_ = 0;
  published_start_frame_ = 0;
  rebuild_version_ = 0;
  published_version_ = 0;
}

EsdfField::Site EsdfField::site_of(const Buffer& buffer, std::uint32_t seed) const {
  const int x = static_cast<int>(seed & 1023u);
  const int y = static_cast<int>((seed >> 10) & 1023u);
  const int z = static_cast<int>((seed >> 20) & 1023u);
  const std::size_t i = cell_index(seed);
  return decode_seed(buffer.word(i), buffer.site_z(i), x, y, z);
}

EsdfField::Site EsdfField::decode_seed(std::uint32_t word, std::uint8_t site_z, int x, int y,
                                       int z) const {
  const Eigen::Vector3i offset = seed_offset(word, site_z);
  Site site;
  site.s = Eigen::Vector3f(site_coordinate(x, offset.x(), site_units_),
                           site_coordinate(y, offset.y(), site_units_),
                           site_coordinate(z, offset.z(), site_units_));
  site.normal = static_cast<int>((word >> 17) & 8191u);
  site.box = (word & kBoxBit) != 0;
  return site;
}

float EsdfField::site_distance(const Site& site, const Eigen::Vector3f& q,
                               Eigen::Vector3f* away) const {
  const Eigen::Vector3f v = q - site.s;
  const int code = site.normal;
  if (site.box || code >= kNormalSteps * kNormalSteps) {
    const float d = v.norm();
    if (away != nullptr) *away = d > 0.0f ? (v / d).eval() : Eigen::Vector3f::Zero();
    if (site.box) return d - kHalfDiagonal;
    // No normal: the nearest surface point may lie up to the disc's radius beside the site.
    return std::sqrt(std::max(d * d - kDiscRadius * kDiscRadius, 0.0f));
  }
  // The distance to the site's disc: across the normal, and beyond the disc's rim beside it.
  const Eigen::Vector3f n(normals_[3 * code], normals_[3 * code + 1], normals_[3 * code + 2]);
  const float h = v.dot(n);
  const Eigen::Vector3f lateral = v - h * n;
  const float rho = lateral.norm();
  Eigen::Vector3f w = h * n;
  if (rho > kDiscRadius) w += lateral * (1.0f - kDiscRadius / rho);
  // Behind the disc, across its normal (towards the map's inside): the map holds the point
  // inside a part, whatever it lies behind. Out of it is along the normal.
  if (h < 0.0f && rho <= kDiscRadius) {
    if (away != nullptr) *away = n;
    return 0.0f;
  }
  const float d = w.norm();
  if (away != nullptr) *away = d > 0.0f ? (w / d).eval() : Eigen::Vector3f::Zero();
  return d;
}

// Propagation keeps each cell's nearest site by the plain distance (boxes less their half
// diagonal); queries take the disc distance over the 27 cells around a point.
inline float EsdfField::propagation_distance(const Site& site, const Eigen::Vector3f& q) {
  const float d = (q - site.s).norm();
  return site.box ? d - kHalfDiagonal : d;
}

template <typename VoxelT>
bool EsdfField::chunk_changed(const Octree<VoxelT>& map, int chunk) const {
  const int cx = chunk % chunks_per_side_;
  const int cy = (chunk / chunks_per_side_) % chunks_per_side_;
  const int cz = chunk / (chunks_per_side_ * chunks_per_side_);
  const int side_voxels = kChunkCells * cell_voxels_;
  const Eigen::Vector3i lo =
      windows_[1 - front_].min_voxel + Eigen::Vector3i(cx, cy, cz) * side_voxels;
  // Every block the chunk's cells sample: the chunk need not be block-aligned, and trilinear
  // samples at its border cells read the voxels one beyond it.
  Eigen::Vector3i b0;
  Eigen::Vector3i b1;
  for (int a = 0; a < 3; ++a) {
    b0[a] = std::max(lo[a] - 1, 0) / kBlockSide;
    b1[a] = std::min(lo[a] + side_voxels, map.voxels_per_side() - 1) / kBlockSide;
  }
  for (int z = b0.z(); z <= b1.z(); ++z) {
    for (int y = b0.y(); y <= b1.y(); ++y) {
      for (int x = b0.x(); x <= b1.x(); ++x) {
        const VoxelBlock<VoxelT>* block =
            map.find_block_at_voxel(Eigen::Vector3i(x, y, z) * kBlockSide);
        if (block != nullptr && block->last_updated_frame > published_start_frame_) return true;
      }
    }
  }
  return false;
}

namespace {
struct Valley {
  enum Kind { none, positive, negative } kind = none;
  Eigen::Vector3f bottom_W = Eigen::Vector3f::Zero();
};

// The bottom of a dip of the TSDF along `dir` from `from_W` (falling there, rising `length` on),
// by bisection on the slope's sign; false where the TSDF reaches zero on the way (no dip) or a
// sample fails.
template <typename VoxelT>
bool bisect_dip(const Octree<VoxelT>& map, const Eigen::Vector3f& from_W,
                const Eigen::Vector3f& dir, float length, Eigen::Vector3f* bottom_W) {
  float lo = 0.0f;
  float hi = length;
  for (int i = 0; i < kValleyBisections; ++i) {
    const float mid = 0.5f * (lo + hi);
    TsdfSample at_mid;
    if (!sample_tsdf(map, from_W + mid * dir, at_mid) || at_mid.tsdf <= 0.0f) return false;
    if (at_mid.gradient.dot(dir) > 0.0f) {
      hi = mid;
    } else {
      lo = mid;
    }
  }
  *bottom_W = from_W + 0.5f * (lo + hi) * dir;
  return true;
}

// Checks the surface point projected from `at_W` (TSDF d_m, unit gradient n, projected `step`
// along -n): where the gradient there has turned against n while the TSDF kept its sign, the
// projection passed an extremum that never reached zero. A positive one is a thin part whose
// TSDF fusion raised above zero (rays grazing past it write free space into its voxels): its
// bottom, searched along -n and then across (the line may pass beside the part), within
// reach_m. A negative one is a gap fusion closed.
template <typename VoxelT>
Valley find_valley(const Octree<VoxelT>& map, const Eigen::Vector3f& at_W, float d_m,
                   const Eigen::Vector3f& n, float step, float reach_m, float voxel_m, float mu_m) {
  Valley out;
  TsdfSample there;
  if (!sample_tsdf(map, at_W - step * n, there)) return out;
  const float v_m = there.tsdf * mu_m;
  const float rise = -there.gradient.dot(n) * mu_m;  // along -n, beyond the projected point
  // Noise about a zero crossing turns gradients too: a dip counts where the TSDF stays a voxel
  // away from zero and rises clearly beyond the point.
  if (!(rise > kValleyRise) || !(std::abs(v_m) >= voxel_m) || v_m * d_m <= 0.0f ||
      there.tsdf >= 1.0f || there.tsdf <= -1.0f) {
    return out;
  }
  if (d_m < 0.0f) {
    out.kind = Valley::negative;
    return out;
  }
  // The projection may have jumped across a part thicker than it, the TSDF crossing zero on
  // the way: no dip then.
  Eigen::Vector3f bottom_W;
  if (!bisect_dip(map, at_W, -n, step, &bottom_W)) return out;
  // That line may pass beside the part: the gradient at its bottom points away from the part,
  // across the line. The dip's bottom along it, within the same reach.
  TsdfSample at_bottom;
  if (sample_tsdf(map, bottom_W, at_bottom)) {
    const float across = at_bottom.gradient.norm();
    if (across > 0.0f) {
      const Eigen::Vector3f m = -at_bottom.gradient / across;
      TsdfSample far;
      const bool rising =
          sample_tsdf(map, bottom_W + reach_m * m, far) && far.gradient.dot(m) > 0.0f;
      Eigen::Vector3f better_W;
      if (rising && bisect_dip(map, bottom_W, m, reach_m, &better_W)) bottom_W = better_W;
    }
  }
  out.bottom_W = bottom_W;
  out.kind = Valley::positive;
  return out;
}
}  // namespace

bool EsdfField::copy_seed(const Eigen::Vector3i& shift_cells, int x, int y, int z,
                          std::uint32_t* word, std::uint8_t* site_z) const {
  const Eigen::Vector3i source = Eigen::Vector3i(x, y, z) + shift_cells;
  // Sites near the published window's faces may have been clamped into it: a moved window
  // takes only cells a margin inside (a seed's site lies within its cell's reach).
  if ((source.array() < kCopyMarginCells).any() ||
      (source.array() >= n_ - kCopyMarginCells).any()) {
    return false;
  }
  const Buffer& front = buffers_[front_];
  const std::size_t i =
      (static_cast<std::size_t>(source.z()) * n_ + static_cast<std::size_t>(source.y())) * n_ +
      static_cast<std::size_t>(source.x());
  *word = kNoSite;
  *site_z = 0;
  if ((front.word(i) & kSeedBit) == 0) return true;
  // The site keeps its offset from the cell, which is cell (x, y, z) of the moved window; it
  // must stay in that window.
  const Eigen::Vector3i units =
      Eigen::Vector3i(x, y, z) * site_units_ + seed_offset(front.word(i), front.site_z(i));
  if ((units.array() < 0).any() || (units.array() >= n_ * site_units_).any()) return false;
  *word = front.word(i);
  *site_z = front.site_z(i);
  return true;
}

template <typename VoxelT>
bool EsdfField::seed_chunk(const Octree<VoxelT>& map, const FreeSpace* free_space, float mu_m,
                           int chunk, bool from_map) {
  const Buffer& back = buffers_[1 - front_];
  const Window& window = windows_[1 - front_];
  // A moved window's cells lie this many cells on from the published window's same cells.
  const Eigen::Vector3i shift_cells =
      (window.min_voxel - windows_[front_].min_voxel) / cell_voxels_;
  const int cx = chunk % chunks_per_side_;
  const int cy = (chunk / chunks_per_side_) % chunks_per_side_;
  const int cz = chunk / (chunks_per_side_ * chunks_per_side_);
  // The same window, unchanged there: each seed stays where it was (a moved window's seeds go
  // through copy_seed()).
  if (!from_map && shift_cells == Eigen::Vector3i::Zero()) {
    const Buffer& front = buffers_[front_];
    for (int z = cz * kChunkCells; z < (cz + 1) * kChunkCells; ++z) {
      for (int y = cy * kChunkCells; y < (cy + 1) * kChunkCells; ++y) {
        const std::size_t row =
            (static_cast<std::size_t>(z) * n_ + static_cast<std::size_t>(y)) * n_;
        for (int x = cx * kChunkCells; x < (cx + 1) * kChunkCells; ++x) {
          const std::uint32_t word = front.word(row + x);
          const bool seed = (word & kSeedBit) != 0;
          back.set_word(row + x, seed ? word : kNoSite);
          back.set_site_z(row + x, seed ? front.site_z(row + x) : 0);
        }
      }
    }
    return false;
  }
  const float half_diagonal_m = kHalfDiagonal * cell_m_;
  const float cv = static_cast<float>(cell_voxels_);
  FreeOctant octant;
  bool any_from_map = from_map;
  // Cells along a row share blocks: look each up once.
  Eigen::Vector3i cached_block_coords = Eigen::Vector3i::Constant(-1);
  const VoxelBlock<VoxelT>* cached_block = nullptr;
  for (int z = cz * kChunkCells; z < (cz + 1) * kChunkCells; ++z) {
    for (int y = cy * kChunkCells; y < (cy + 1) * kChunkCells; ++y) {
      for (int x = cx * kChunkCells; x < (cx + 1) * kChunkCells; ++x) {
        const std::size_t index =
            (static_cast<std::size_t>(z) * n_ + static_cast<std::size_t>(y)) * n_ + x;
        std::uint32_t copied_word = kNoSite;
        std::uint8_t copied_z = 0;
        const bool copied = !from_map && copy_seed(shift_cells, x, y, z, &copied_word, &copied_z);
        back.set_word(index, copied_word);
        back.set_site_z(index, copied_z);
        if (copied) continue;
        any_from_map = true;
        // The finest voxel holding the cell's centre (cells are whole voxels on the map's cell
        // grid). The window lies inside the cube, and so does every cell's voxel.
        const Eigen::Vector3i voxel = window.min_voxel + Eigen::Vector3i(x, y, z) * cell_voxels_ +
                                      Eigen::Vector3i::Constant(cell_voxels_ / 2);
        const Eigen::Vector3i block_coords = voxel_to_block(voxel);
        if (block_coords != cached_block_coords) {
          cached_block_coords = block_coords;
          cached_block = map.find_block(block_coords);
        }
        const VoxelBlock<VoxelT>* block = cached_block;
        // A cell lies in one block (cells sit on the map's cell grid, blocks are whole cells or
        // whole blocks of cells), and so do the corner points below: without a block nothing
        // samples, and only unknown-as-obstacle makes a site.
        if (block == nullptr && !config_.unknown_is_obstacle) continue;
        bool observed = false;
        bool box = false;
        bool site = false;
        bool valley_site = false;  // a box around a dip's bottom, not around the cell's centre
        int normal = kNoNormal;
        Eigen::Vector3f site_W = Eigen::Vector3f::Zero();  // of a site not at the cell's centre
        // With unknown space as obstacle, a cell whose centre is unobserved stays one.
        if (block != nullptr || !config_.unknown_is_obstacle) {
          // The cell's centre in continuous finest-voxel coordinates, and in the world.
          const Eigen::Vector3f q = window.min_voxel.cast<float>() +
                                    (Eigen::Vector3f(static_cast<float>(x), static_cast<float>(y),
                                                     static_cast<float>(z)) +
                                     Eigen::Vector3f::Constant(0.5f)) *
                                        cv;
          const Eigen::Vector3f p_W = map.config().origin_W + q * voxel_m_;
          // The trilinear sample needs all 8 voxels around its point observed: where the
          // cell's centre lacks one (the edge of what the camera saw, a scale boundary, a block
          // never allocated beside a surface), a point a quarter cell towards each corner may
          // have them.
          TsdfSample sample;
          Eigen::Vector3f at_W = p_W;
          bool sampled = block != nullptr && sample_tsdf(map, p_W, block, sample);
          for (int corner = 0; !sampled && corner < 8; ++corner) {
            const Eigen::Vector3f offset((corner & 1) ? 0.25f : -0.25f,
                                         (corner & 2) ? 0.25f : -0.25f,
                                         (corner & 4) ? 0.25f : -0.25f);
            at_W = p_W + offset * cell_m_;
            sampled = sample_tsdf(map, at_W, sample);
          }
          if (sampled) {
            observed = true;
            float d_m = sample.tsdf * mu_m;
            Eigen::Vector3f g = sample.gradient * mu_m;
            const float slope = g.norm();
            if (sample.tsdf > -1.0f && sample.tsdf < 1.0f && slope > 0.2f) {
              // Ray distances exceed Euclidean ones by the gradient's length on slanted
              // surfaces. In front of a surface a flatter gradient (blending, truncation) says
              // nothing: the surface lies no further than the sample reads. Behind one, fusion
              // averages thin parts' insides towards zero: the gradient's length counts there.
              const Eigen::Vector3f n = g / slope;
              const float step = d_m / (d_m > 0.0f ? std::max(slope, 1.0f) : slope);
              const float reach = half_diagonal_m + voxel_m_;
              const Valley valley =
                  std::abs(step) <= kValleyReach * reach
                      ? find_valley(map, at_W, d_m, n, step, reach, voxel_m_, mu_m)
                      : Valley();
              // A dip is looked for a little further than a site is projected: beside thin
              // parts the TSDF reads several times the distance. Only one within reach makes a
              // site (a seed keeps its site, and one far off would hide its neighbours' nearer
              // ones from queries).
              if (valley.kind == Valley::positive && (valley.bottom_W - at_W).norm() <= reach) {
                // The part lies around the dip's bottom, in no known direction, and the bottom
                // is found to about a cell: the site is a box there.
                site = true;
                valley_site = true;
                site_W = valley.bottom_W;
              } else if (valley.kind == Valley::negative && std::abs(step) <= reach) {
                site = true;
                box = true;
              } else if (std::abs(step) <= reach) {
                site = true;
                site_W = at_W - step * n;
                normal = encode_normal(g);
              } else if (d_m < 0.0f) {
                site = true;
                box = true;
              }
            } else if (sample.tsdf <= 0.0f) {
              site = true;
              box = true;
            }
          } else if (block != nullptr) {
            const VoxelT& v = block->at_voxel(voxel, block_read_scale(*block));
            if (voxel_observed(v)) {
              observed = true;
              const float d_m = voxel_tsdf(v) * mu_m;
              // No gradient here: the whole cell is the obstacle where a surface may cross it.
              if (d_m <= half_diagonal_m + voxel_m_) {
                site = true;
                box = true;
              }
            }
          }
        }
        if (!observed && config_.unknown_is_obstacle) {
          // Octants, free or known to hold nothing free, are mostly larger than a cell: look
          // each up once.
          if (octant.size_voxels == 0 || (voxel.array() < octant.min_voxel.array()).any() ||
              (voxel.array() >= (octant.min_voxel.array() + octant.size_voxels)).any()) {
            if (free_space != nullptr) octant = free_space->find(voxel);
          }
          const bool known_free =
              octant.free && (voxel.array() >= octant.min_voxel.array()).all() &&
              (voxel.array() < (octant.min_voxel.array() + octant.size_voxels)).all();
          if (!known_free) {
            site = true;
            box = true;
          }
        }
        if (site) {
          const int u = site_units_;
          // A box around the cell's centre sits half a cell from its corner.
          std::uint32_t ox = static_cast<std::uint32_t>(u / 2 + kOffsetBias);
          std::uint32_t oy = ox;
          std::uint32_t oz = ox;
          if (!box || valley_site) {
            const Eigen::Vector3f s_cells = (site_W - window.min_W) / cell_m_;
            ox = offset_byte(to_site_units(s_cells.x(), n_, u), x * u, kOffsetBias);
            oy = offset_byte(to_site_units(s_cells.y(), n_, u), y * u, kOffsetBias);
            oz = offset_byte(to_site_units(s_cells.z(), n_, u), z * u, kOffsetBias);
          }
          box = box || valley_site;
          const std::uint32_t code = static_cast<std::uint32_t>(box ? kNoNormal : normal);
          back.set_word(index,
                        kSeedBit | (box ? kBoxBit : 0u) | (code << 17) | (ox << 9) | (oy << 1));
          back.set_site_z(index, static_cast<std::uint8_t>(oz));
        }
      }
    }
  }
  return any_from_map;
}

// One slice of a sweep along z (dz = +1 forward, -1 backward): the site of the cell before it
// along z, then a two-pass 2D propagation inside the slice (the row before, then along the row
// both ways; rows up, then rows down), so a site reaches every cell of the slice in one sweep.
// Seeds keep their own surface point: a later rebuild copies them where the map did not change,
// and the 27 cells a query reads hold the neighbours' sites anyway.
void EsdfField::sweep_slice(int z, int dz) {
  const Buffer& back = buffers_[1 - front_];
  const int n = n_;
  const std::size_t slice = static_cast<std::size_t>(n) * static_cast<std::size_t>(n);
  const std::size_t here = static_cast<std::size_t>(z) * slice;
  const int zp = z - dz;
  const bool has_prev = zp >= 0 && zp < n;
  // The slice before along the sweep, as swept (a budget may have stopped between the two): its
  // sites decoded, each cell's seed.
  const int prev_half = cached_half_;
  float* prev_cache = slice_cache_ + kSliceFloats * slice * prev_half;
  std::uint32_t* prev_seeds = slice_seeds_ + slice * prev_half;
  const bool prev_cached = has_prev && cached_slice_z_ == zp && cached_slice_dz_ == dz;
  float* cache = slice_cache_ + kSliceFloats * slice * (1 - prev_half);
  std::uint32_t* seeds = slice_seeds_ + slice * (1 - prev_half);
  // This slice, once swept, is the one before the next.
  cached_half_ = 1 - prev_half;
  cached_slice_z_ = z;
  cached_slice_dz_ = dz;
  const float zc = static_cast<float>(z) + 0.5f;
  // Per cell of the slice: site x, y, z (cells), less (a box's half diagonal, else 0), distance.
  auto store = [](float* c, const Eigen::Vector3f& s, bool box, float distance) {
    c[0] = s.x();
    c[1] = s.y();
    c[2] = s.z();
    c[3] = box ? kHalfDiagonal : 0.0f;
    c[4] = distance;
  };
  // From q to a cached site: what propagation_distance() gives for it.
  auto distance_to = [](const float* c, const Eigen::Vector3f& q) {
    return (q - Eigen::Vector3f(c[0], c[1], c[2])).norm() - c[3];
  };
  // The distance of cell i (centre q) to its site, computed when first asked.
  constexpr float kNotYet = -2e30f;
  auto distance_of = [cache, &distance_to](std::size_t i, const Eigen::Vector3f& q) {
    float* c = cache + kSliceFloats * i;
    if (c[4] == kNotYet) c[4] = distance_to(c, q);
    return c[4];
  };
  // A slice's seeds and decoded sites from its words. Neighbours mostly share seeds, and so do
  // cells along z: a seed is decoded once for a run of cells, or taken from the slice before.
  auto load = [&](int at_z, float* to_cache, std::uint32_t* to_seeds, const float* from_cache,
                  const std::uint32_t* from_seeds) {
    const std::size_t at = static_cast<std::size_t>(at_z) * slice;
    std::uint32_t decoded_seed = kNoSite;
    Site decoded;
    bool any_site = false;
    for (int y = 0; y < n; ++y) {
      open_rows_[y] = 0;
      for (int x = 0; x < n; ++x) {
        const std::size_t i = static_cast<std::size_t>(y) * n + x;
        float* c = to_cache + kSliceFloats * i;
        const std::uint32_t w = back.word(at + i);
        if (w == kNoSite) {
          to_seeds[i] = kNoSite;
          open_rows_[y] = 1;
          store(c, Eigen::Vector3f::Zero(), false, 1e30f);
          continue;
        }
        any_site = true;
        if ((w & kSeedBit) != 0) {
          // A seed's own cell is never replaced (and never asked). Its site as decode_seed()
          // gives it, from the word already read: most cells are seeds where unknown space is an
          // obstacle.
          to_seeds[i] = pack_cell(x, y, at_z) | kSeedBit;
          const Eigen::Vector3i offset = seed_offset(w, back.site_z(at + i));
          const Eigen::Vector3f s(site_coordinate(x, offset.x(), site_units_),
                                  site_coordinate(y, offset.y(), site_units_),
                                  site_coordinate(at_z, offset.z(), site_units_));
          store(c, s, (w & kBoxBit) != 0, -1e30f);
          continue;
        }
        // Any other cell holds its seed's coordinates. One whose neighbours share its seed is
        // never compared: its distance waits until asked.
        open_rows_[y] = 1;
        to_seeds[i] = w;
        if (from_seeds != nullptr && (from_seeds[i] & ~kSeedBit) == w) {
          std::copy(from_cache + kSliceFloats * i, from_cache + kSliceFloats * i + 4, c);
          c[4] = kNotYet;
          continue;
        }
        if (w != decoded_seed) {
          decoded = site_of(back, w);
          decoded_seed = w;
        }
        store(c, decoded.s, decoded.box, kNotYet);
      }
    }
    return any_site;
  };
  if (has_prev && !prev_cached) {
    load(zp, prev_cache, prev_seeds, nullptr, nullptr);
  }
  bool any_site =
      load(z, cache, seeds, has_prev ? prev_cache : nullptr, has_prev ? prev_seeds : nullptr);
  // Cell i (centre q) takes `seed`, whose site `from` holds, where it is nearer: true if so.
  auto take = [&](std::size_t i, std::uint32_t seed, const float* from, const Eigen::Vector3f& q) {
    if (seed == seeds[i]) return false;
    const float candidate = distance_to(from, q);
    if (candidate >= distance_of(i, q)) return false;
    seeds[i] = seed;
    float* to = cache + kSliceFloats * i;
    std::copy(from, from + 4, to);  // the site and its `less`
    to[4] = candidate;
    return true;
  };
  // Only cells that are not seeds take sites, and rows of seeds alone are passed over.
  for (int y = 0; has_prev && y < n; ++y) {
    if (open_rows_[y] == 0) continue;
    for (int x = 0; x < n; ++x) {
      const std::size_t i = static_cast<std::size_t>(y) * n + x;
      const std::uint32_t from = prev_seeds[i];
      if (from == kNoSite || (seeds[i] & kSeedBit) != 0) continue;
      const Eigen::Vector3f q(static_cast<float>(x) + 0.5f, static_cast<float>(y) + 0.5f, zc);
      if (take(i, from & ~kSeedBit, prev_cache + kSliceFloats * i, q)) any_site = true;
    }
  }
  // A slice without a site (ahead of every surface along the sweep) keeps its words.
  if (!any_site) return;
  // Cell i takes the site of cell j of the slice where it is nearer.
  auto consider = [&](std::size_t i, std::size_t j, const Eigen::Vector3f& q) {
    take(i, seeds[j] & ~kSeedBit, cache + kSliceFloats * j, q);
  };
  for (int pass = 0; pass < 2; ++pass) {
    const int dy = pass == 0 ? 1 : -1;
    for (int step = 0; step < n; ++step) {
      const int y = dy > 0 ? step : n - 1 - step;
      if (open_rows_[y] == 0) continue;
      const std::size_t row = static_cast<std::size_t>(y) * n;
      const int yp = y - dy;
      const bool has_prev_row = yp >= 0 && yp < n;
      const std::size_t prev_row = static_cast<std::size_t>(has_prev_row ? yp : y) * n;
      const float yc = static_cast<float>(y) + 0.5f;
      for (int x = 0; x < n; ++x) {
        const std::uint32_t above = has_prev_row ? seeds[prev_row + x] : kNoSite;
        const std::uint32_t left = x > 0 ? seeds[row + x - 1] : kNoSite;
        if ((seeds[row + x] & kSeedBit) != 0 || (above == kNoSite && left == kNoSite)) continue;
        const Eigen::Vector3f q(static_cast<float>(x) + 0.5f, yc, zc);
        if (above != kNoSite) consider(row + x, prev_row + x, q);
        if (left != kNoSite) consider(row + x, row + x - 1, q);
      }
      for (int x = n - 2; x >= 0; --x) {
        if ((seeds[row + x] & kSeedBit) != 0 || seeds[row + x + 1] == kNoSite) continue;
        const Eigen::Vector3f q(static_cast<float>(x) + 0.5f, yc, zc);
        consider(row + x, row + x + 1, q);
      }
    }
  }
  // Seeds' own words never change; every other cell refers to its seed.
  for (int y = 0; y < n; ++y) {
    if (open_rows_[y] == 0) continue;
    for (std::size_t i = static_cast<std::size_t>(y) * n; i < static_cast<std::size_t>(y + 1) * n;
         ++i) {
      if ((seeds[i] & kSeedBit) == 0) back.set_word(here + i, seeds[i]);
    }
  }
}

void EsdfField::publish(bool swap) {
  auto make_current = [this, swap] {
    if (swap) front_ = 1 - front_;
    published_version_ = rebuild_version_;
  };
  // Readers see the old field or the new one, never a mix.
  if (guard_ != nullptr) {
    ExclusiveHold hold(*guard_);
    make_current();
  } else {
    make_current();
  }
  front_valid_ = true;
  have_published_ = true;
  published_start_frame_ = rebuild_start_frame_;
  phase_ = Phase::idle;
}

template <typename VoxelT>
EsdfReport EsdfField::advance(const Octree<VoxelT>& map, const FreeSpace* free_space, float mu_m,
                              std::uint32_t frame, std::uint64_t map_version,
                              std::uint64_t budget) {
  EsdfReport report;
  if (!reserved()) return report;
  std::uint64_t steps = 0;
  const int chunks = chunks_per_side_ * chunks_per_side_ * chunks_per_side_;
  const std::uint64_t slice_cells = static_cast<std::uint64_t>(n_) * static_cast<std::uint64_t>(n_);
  for (;;) {
    if (phase_ == Phase::idle) {
      // A window moved by centre_on() is rebuilt even where the map did not change.
      const bool moved = target_.min_voxel != windows_[front_].min_voxel;
      if (have_published_ && map_version == published_version_ && !all_dirty_ && !moved) break;
      if (have_published_ && map_version == rebuild_version_ && !all_dirty_ && !moved) break;
      phase_ = Phase::seed;
      cursor_ = 0;
      rebuild_start_frame_ = frame;
      rebuild_version_ = map_version;
      windows_[1 - front_] = target_;
      rebuild_all_ = all_dirty_ || !front_valid_ || config_.unknown_is_obstacle;
      all_dirty_ = false;
      rebuild_chunks_from_map_ = 0;
    }
    if (steps >= budget) {
      report.budget_hit = true;
      break;
    }
    if (phase_ == Phase::seed) {
      const bool from_map = rebuild_all_ || chunk_changed(map, cursor_);
      if (seed_chunk(map, free_space, mu_m, cursor_, from_map)) {
        ++report.chunks_reseeded;
        ++rebuild_chunks_from_map_;
      }
      steps += kChunkCells * kChunkCells * kChunkCells;
      if (++cursor_ == chunks) {
        phase_ = Phase::forward;
        cursor_ = 0;
        // The map changed only outside the window (no chunk seeded from it, the window where
        // it was): the seeds are the published field's, and so would the sweeps' result be.
        // The published field stands for the new map version as it is.
        if (!rebuild_all_ && rebuild_chunks_from_map_ == 0 &&
            windows_[1 - front_].min_voxel == windows_[front_].min_voxel) {
          publish(false);
          report.published = true;
          break;
        }
      }
    } else if (phase_ == Phase::forward) {
      sweep_slice(cursor_, 1);
      steps += slice_cells;
      if (++cursor_ == n_) {
        phase_ = Phase::backward;
        cursor_ = n_ - 1;
      }
    } else {
      sweep_slice(cursor_, -1);
      steps += slice_cells;
      if (--cursor_ < 0) {
        publish(true);
        report.published = true;
        // One rebuild per call at most: the next frame starts the next one.
        break;
      }
    }
  }
  report.cell_steps = static_cast<std::uint32_t>(std::min<std::uint64_t>(steps, 0xFFFFFFFFu));
  report.rebuilding = phase_ != Phase::idle;
  return report;
}

template <typename VoxelT>
EsdfReport EsdfField::update(const Octree<VoxelT>& map, const FreeSpace* free_space, float mu_m,
                             std::uint32_t frame, std::uint64_t map_version) {
  const std::uint64_t budget =
      config_.max_cell_steps > 0 ? config_.max_cell_steps : ~static_cast<std::uint64_t>(0);
  return advance(map, free_space, mu_m, frame, map_version, budget);
}

template <typename VoxelT>
EsdfReport EsdfField::flush(const Octree<VoxelT>& map, const FreeSpace* free_space, float mu_m,
                            std::uint32_t frame, std::uint64_t map_version) {
  EsdfReport report = advance(map, free_space, mu_m, frame, map_version, ~std::uint64_t(0));
  if (!report.published || map_version != published_version_) {
    const EsdfReport again = advance(map, free_space, mu_m, frame, map_version, ~std::uint64_t(0));
    report.cell_steps += again.cell_steps;
    report.chunks_reseeded += again.chunks_reseeded;
    report.published = report.published || again.published;
    report.rebuilding = again.rebuilding;
  }
  return report;
}

EsdfAnswer EsdfField::answer_unguarded(const Eigen::Vector3f& p_W) const {
  EsdfAnswer out;
  out.map_version = published_version_;
  const Window& window = windows_[front_];
  const Eigen::Vector3f q = (p_W - window.min_W) / cell_m_;  // in cells
  const float n = static_cast<float>(n_);
  if (!(q.x() >= 0.0f && q.y() >= 0.0f && q.z() >= 0.0f && q.x() < n && q.y() < n && q.z() < n)) {
    return out;
  }
  // Surfaces beyond the window's faces inside the cube are not in the field.
  float window_bound = 1e30f;
  for (int a = 0; a < 3; ++a) {
    if (window.open_face[a][0]) window_bound = std::min(window_bound, q[a]);
    if (window.open_face[a][1]) window_bound = std::min(window_bound, n - q[a]);
  }
  window_bound *= cell_m_;
  const int x = static_cast<int>(q.x());
  const int y = static_cast<int>(q.y());
  const int z = static_cast<int>(q.z());
  const Buffer& cells = buffers_[front_];
  // First the seeds of the 27 cells (in order, each once), then their sites: the sites' reads
  // are independent of each other, so their cache misses overlap.
  std::uint32_t seeds[27];
  Site sites[27];
  bool from_elsewhere[27] = {};  // a seed that lies outside the 27 cells, read after them
  int seed_count = 0;
  for (int dz = -1; dz <= 1; ++dz) {
    for (int dy = -1; dy <= 1; ++dy) {
      for (int dx = -1; dx <= 1; ++dx) {
        const int nx = x + dx;
        const int ny = y + dy;
        const int nz = z + dz;
        if (nx < 0 || ny < 0 || nz < 0 || nx >= n_ || ny >= n_ || nz >= n_) continue;
        const std::size_t i =
            (static_cast<std::size_t>(nz) * n_ + static_cast<std::size_t>(ny)) * n_ + nx;
        const std::uint32_t w = cells.word(i);
        if (w == kNoSite) continue;
        if ((w & kSeedBit) != 0) {
          // A seed's own cell comes once, and holds its site.
          sites[seed_count] = decode_seed(w, cells.site_z(i), nx, ny, nz);
          seeds[seed_count++] = pack_cell(nx, ny, nz);
          continue;
        }
        // A cell that took a seed's site may repeat one.
        if (std::find(seeds, seeds + seed_count, w) != seeds + seed_count) continue;
        from_elsewhere[seed_count] = true;
        seeds[seed_count++] = w;
      }
    }
  }
  for (int k = 0; k < seed_count; ++k) {
    if (from_elsewhere[k]) sites[k] = site_of(cells, seeds[k]);
  }
  float best = 1e30f;
  bool found = false;
  Eigen::Vector3f best_away = Eigen::Vector3f::Zero();
  for (int k = 0; k < seed_count; ++k) {
    Eigen::Vector3f away;
    const float d = site_distance(sites[k], q, &away);
    if (d < best) {
      found = true;
      best = d;
      best_away = away;
    }
  }
  if (!found) {
    out.lower_bound_m = window_bound < 1e29f ? window_bound : 0.0f;
    return out;
  }
  out.has_distance = true;
  // A surface beyond the window's faces may be nearer than any site: no more than the distance
  // to those faces.
  out.distance_m = std::min(std::max(best, 0.0f) * cell_m_, window_bound);
  out.gradient = best_away;
  out.error_bound_m = error_bound_m_;
  out.lower_bound_m = std::max(out.distance_m - error_bound_m_, 0.0f);
  return out;
}

Result<EsdfAnswer> EsdfField::distance(const Eigen::Vector3f& p_W) const {
  if (!finite(p_W)) return Status(StatusCode::invalid_argument);
  SharedHold hold(guard_);
  if (!reserved()) return EsdfAnswer();
  return answer_unguarded(p_W);
}

Status EsdfField::distances(const Eigen::Vector3f* points_W, std::size_t count,
                            EsdfAnswer* out) const {
  SharedHold hold(guard_);
  Status status = ok_status();
  for (std::size_t i = 0; i < count; ++i) {
    if (!finite(points_W[i])) {
      status = Status(StatusCode::invalid_argument);
      continue;
    }
    out[i] = reserved() ? answer_unguarded(points_W[i]) : EsdfAnswer();
  }
  return status;
}

#define OCTOFUSE_ESDF_INSTANTIATE(VoxelT)                                               \
  template EsdfReport EsdfField::update(const Octree<VoxelT>&, const FreeSpace*, float, \
                                        std::uint32_t, std::uint64_t);                  \
  template EsdfReport EsdfField::flush(const Octree<VoxelT>&, const FreeSpace*, float,  \
                                       std::uint32_t, std::uint64_t);
OCTOFUSE_ESDF_INSTANTIATE(TsdfVoxel)
OCTOFUSE_ESDF_INSTANTIATE(MultiresVoxel)
OCTOFUSE_ESDF_INSTANTIATE(Multires16Voxel)
#undef OCTOFUSE_ESDF_INSTANTIATE

}  // namespace octofuse
