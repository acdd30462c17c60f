#include "octofuse/render/raycaster.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "octofuse/core/lanes.hpp"
#include "octofuse/map/interpolation.hpp"

namespace octofuse {
namespace {

// Past an empty octant's far face by this fraction of a voxel, so the next lookup lands inside
// the following octant despite rounding.
constexpr float kExitNudge_voxels = 1e-3f;
// Step through unobserved voxels of allocated blocks, as a fraction of mu.
constexpr float kUnobservedStep_mu = 0.5f;
// Smallest gap, in finest voxels, that is still halved when a step lands on unobserved voxels.
constexpr float kRetreatMin_voxels = 1.5f;
// Scales whose voxels are so large that mu spans fewer than this many of them (2 mm voxels with
// the default mu of 8: scales 2 and 3) hold a band only a voxel or two thick. There the trilinear
// cell around a crossing often reaches a voxel no update reached or a block never allocated, and
// the march below treats samples near a crossing specially.
constexpr float kThinBand_cells = 5.0f;
// At such scales: a negative sample after samples that failed still closes a crossing with the
// last positive sample before them when it lies at most this far (a fraction of mu) behind it
// (one step through unobserved voxels plus the backed-off gap) ...
constexpr float kBridge_mu = 0.75f;
// ... and where a crossing is expected (after a positive sample, or at a guided start) and the
// full sample fails, the cell is read from its observed corners when they carry at least this
// share of its trilinear weight.
constexpr float kMinObservedWeight = 0.25f;
// Above this normalised TSDF the nearest voxel alone chooses the step; the full trilinear sample
// is only taken closer to the surface.
constexpr float kFarTsdf = 0.25f;
// A guided ray starts this far in front of its guide depth, as a fraction of mu: inside the band
// the integrator just wrote, close enough to skip most of it, far enough that depth noise rarely
// puts the fused surface in front of the start (which then costs a full march).
constexpr float kGuideMargin_mu = 0.5f;
// In a guided cast, a pixel without a guide whose ray found nothing in the previous cast is marched
// again only every this many casts (pixels take turns); in between it stays empty, as it was.
constexpr std::uint32_t kMissRetryPeriod = 4;
// Distance from a point to the centre of the voxel containing it, at most, in cells.
constexpr float kNearestOffset_cells = 0.8661f;

struct Ray {
  Eigen::Vector3f origin_W;
  Eigen::Vector3f dir_W;  // unit
};

struct PixelHit {
  Eigen::Vector3f p_W;
  Eigen::Vector3f n_W;
  int scale;
};

// rejected: a guided march started behind a surface or in unobserved space (march it in full).
enum class MarchResult { hit, miss, out_of_steps, rejected };

// Finds the block or free octant holding a voxel by descending from a cached ancestor node (a few
// levels above the blocks) instead of probing the hash and walking from the root: consecutive
// steps of a ray mostly stay under the same ancestor, whose nodes stay in cache.
template <typename VoxelT>
class TreeCursor {
 public:
  explicit TreeCursor(const Octree<VoxelT>& map)
      : map_(map),
        depth_(map.voxel_depth()),
        block_level_(map.block_level()),
        anchor_level_(std::max(0, map.block_level() - kAnchorLevelsAboveBlocks)) {}

  // Same answer as Octree::lookup(voxel); `voxel` must be inside the cube.
  OctantLookup find(const Eigen::Vector3i& voxel) {
    // Most lookups land in the 2x2x2 blocks under the last block parent: one child read.
    if (parent_children_ != nullptr) {
      const Eigen::Vector3i d = voxel - parent_corner_;
      constexpr unsigned side = kParentSide;
      if (static_cast<unsigned>(d.x()) < side && static_cast<unsigned>(d.y()) < side &&
          static_cast<unsigned>(d.z()) < side) {
        const int child = (d.x() >> kBlockSideLog2) | ((d.y() >> kBlockSideLog2) << 1) |
                          ((d.z() >> kBlockSideLog2) << 2);
        OctantLookup out;
        out.block = parent_children_[child];
        out.level = out.block == kNoIndex ? block_level_ - 1 : block_level_;
        out.node = parent_;
        return out;
      }
    }
    if (anchor_ == kNoIndex || !inside_anchor(voxel)) reanchor(voxel);
    const OctantLookup out = map_.lookup_from(voxel, anchor_, anchor_node_level_);
    if (out.level >= block_level_ - 1) {
      parent_ = out.node;
      parent_children_ = map_.node(out.node).children;
      parent_corner_ =
          Eigen::Vector3i(voxel.x() & ~(kParentSide - 1), voxel.y() & ~(kParentSide - 1),
                          voxel.z() & ~(kParentSide - 1));
    }
    return out;
  }

 private:
  static constexpr int kAnchorLevelsAboveBlocks = 3;
  // Side, in voxels, of a node holding blocks (2 blocks).
  static constexpr int kParentSide = 2 * kBlockSide;

  bool inside_anchor(const Eigen::Vector3i& voxel) const {
    const Eigen::Vector3i d = voxel - anchor_corner_;
    return d.x() >= 0 && d.y() >= 0 && d.z() >= 0 && d.x() < anchor_size_ && d.y() < anchor_size_ &&
           d.z() < anchor_size_;
  }

  void reanchor(const Eigen::Vector3i& voxel) {
    std::uint32_t node = Octree<VoxelT>::root_index();
    int level = 0;
    while (level < anchor_level_) {
      const int bit = depth_ - level - 1;
      const int child = ((voxel.x() >> bit) & 1) | (((voxel.y() >> bit) & 1) << 1) |
                        (((voxel.z() >> bit) & 1) << 2);
      const std::uint32_t next = map_.node(node).children[child];
      if (next == kNoIndex) break;
      node = next;
      ++level;
    }
    const int shift = depth_ - level;
    anchor_ = node;
    anchor_node_level_ = level;
    anchor_size_ = 1 << shift;
    anchor_corner_ = Eigen::Vector3i((voxel.x() >> shift) << shift, (voxel.y() >> shift) << shift,
                                     (voxel.z() >> shift) << shift);
  }

  const Octree<VoxelT>& map_;
  int depth_;
  int block_level_;
  int anchor_level_;
  std::uint32_t parent_ = kNoIndex;  // the last lookup's node of level block_level - 1
  const std::uint32_t* parent_children_ = nullptr;  // its children
  Eigen::Vector3i parent_corner_ = Eigen::Vector3i::Zero();
  std::uint32_t anchor_ = kNoIndex;
  int anchor_node_level_ = 0;
  int anchor_size_ = 0;
  Eigen::Vector3i anchor_corner_ = Eigen::Vector3i::Zero();
};

// The ray in continuous finest-voxel coordinates (Octree::point_to_voxel_f), still parameterised
// by metres along the unit world ray: q(t) = origin_v + t * dir_v.
struct VoxelRay {
  Eigen::Vector3f origin_v;
  Eigen::Vector3f dir_v;
  Eigen::Vector3f inv_dir_v;  // 1 / dir_v, infinite along axes the ray does not move
};

// Clips [t0, t1] to where the ray is inside the cube [0, side_v]^3 (voxel units); false when it
// misses. Multiplies by the inverse direction instead of dividing per ray.
bool clip_to_cube(const VoxelRay& ray, float side_v, float& t0, float& t1) {
  for (int a = 0; a < 3; ++a) {
    const float o = ray.origin_v[a];
    if (ray.dir_v[a] == 0.0f) {
      if (o < 0.0f || o > side_v) return false;
      continue;
    }
    float ta = (0.0f - o) * ray.inv_dir_v[a];
    float tb = (side_v - o) * ray.inv_dir_v[a];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
  return t0 <= t1;
}

// Distance along the ray at which it leaves the octant [corner, corner + size) (voxel units) it is
// inside.
float octant_exit(const VoxelRay& ray, const Eigen::Vector3i& corner, int size) {
  float t = std::numeric_limits<float>::max();
  for (int a = 0; a < 3; ++a) {
    const float d = ray.dir_v[a];
    if (d > 0.0f) {
      t = std::min(t, (static_cast<float>(corner[a] + size) - ray.origin_v[a]) * ray.inv_dir_v[a]);
    } else if (d < 0.0f) {
      t = std::min(t, (static_cast<float>(corner[a]) - ray.origin_v[a]) * ray.inv_dir_v[a]);
    }
  }
  return t;
}

// Whether the 8 corners of the trilinear cell around q (continuous finest-voxel coordinates) at
// `scale` all lie in `block`: the test sample_tsdf_at_voxel_coords makes for its fast path.
template <typename VoxelT>
bool cell_inside_block(const VoxelBlock<VoxelT>& block, const Eigen::Vector3f& q, int scale) {
  const int side = block_scale_side(scale);
  const Eigen::Vector3f qs =
      q * (1.0f / static_cast<float>(1 << scale)) - Eigen::Vector3f::Constant(0.5f);
  const Eigen::Vector3i block_min = block.min_voxel();
  for (int a = 0; a < 3; ++a) {
    const int local = floor_to_int(qs[a]) - (block_min[a] >> scale);
    if (local < 0 || local >= side - 1) return false;
  }
  return true;
}

// The finest scale whose band is thin (kThinBand_cells); kMaxBlockScale + 1 when none is.
int thin_band_scale(float mu_m, float voxel_m) {
  for (int s = 0; s <= kMaxBlockScale; ++s) {
    if (mu_m < kThinBand_cells * voxel_m * static_cast<float>(1 << s)) return s;
  }
  return kMaxBlockScale + 1;
}

// What one ray leaves for the next: neighbouring rays descend through the same nodes and sample
// the same blocks, so a row keeps one cursor and one block neighbourhood for all its rays.
template <typename VoxelT>
struct RowCache {
  RowCache(const Octree<VoxelT>& map, float mu_m)
      : cursor(map), thin_scale(thin_band_scale(mu_m, map.voxel_size_m())) {}
  TreeCursor<VoxelT> cursor;
  BlockNeighbourhood<VoxelT> neighbourhood;
  int thin_scale;
};

// Inside the cube q is non-negative, so truncation is floor (and NaN fails the test).
inline bool inside_cube(const Eigen::Vector3f& q, float side_v) {
  return q.x() >= 0.0f && q.y() >= 0.0f && q.z() >= 0.0f && q.x() < side_v && q.y() < side_v &&
         q.z() < side_v;
}

// The block a march is in. Consecutive samples mostly fall in the same block: it is looked up
// only when the block changes.
template <typename VoxelT>
struct MarchBlock {
  const VoxelBlock<VoxelT>* block = nullptr;     // null: a free octant
  int scale = 0;                                 // the block's read scale ...
  const VoxelT* level = nullptr;                 // ... and that level's voxels (scale 1-3 of a
  const FinestVoxelT<VoxelT>* finest = nullptr;  // multires block; scale 0 here)
  Eigen::Vector3i coords = Eigen::Vector3i::Constant(-1);
  OctantLookup where;
};

template <typename VoxelT>
inline void enter_block(const Octree<VoxelT>& map, TreeCursor<VoxelT>& cursor,
                        const Eigen::Vector3i& voxel, MarchBlock<VoxelT>& at) {
  const Eigen::Vector3i coords = voxel_to_block(voxel);
  if (coords == at.coords) return;
  at.where = cursor.find(voxel);
  at.block = at.where.block == kNoIndex ? nullptr : &map.block(at.where.block);
  if (at.block != nullptr) {
    at.scale = block_read_scale(*at.block);
    if (at.scale == 0) {
      at.finest = at.block->finest_begin();
    } else {
      at.level = at.block->level_begin(at.scale);
    }
  }
  at.coords = coords;
}

// The field at voxel coordinates q (false where it fails), in the block `home` (at block
// coordinates home_coords) or one the cursor finds. Only around a hit: out of line, so the
// march's loop stays small.
template <typename VoxelT>
__attribute__((noinline)) bool sample_field_at(const Octree<VoxelT>& map, RowCache<VoxelT>& cache,
                                               const VoxelBlock<VoxelT>* home,
                                               Eigen::Vector3i home_coords,
                                               const Eigen::Vector3f& q, TsdfSample& out) {
  const float side_v = static_cast<float>(map.voxels_per_side());
  const VoxelBlock<VoxelT>* block = nullptr;
  if (inside_cube(q, side_v)) {
    const Eigen::Vector3i v = q.cast<int>();
    if (voxel_to_block(v) == home_coords) {
      block = home;
    } else {
      const OctantLookup found = cache.cursor.find(v);
      block = found.block == kNoIndex ? nullptr : &map.block(found.block);
    }
  }
  return sample_tsdf_at_voxel_coords(map, q, block, cache.neighbourhood, out);
}

// Where the ray leaves the free octant holding `voxel` (the lookup stopped at `level`), a
// little past its far face.
template <typename VoxelT>
inline float free_octant_exit(const Octree<VoxelT>& map, const VoxelRay& ray_v,
                              const Eigen::Vector3i& voxel, int level, float t) {
  const int free_level = std::min(level + 1, map.block_level());
  const int shift = map.voxel_depth() - free_level;
  const Eigen::Vector3i corner((voxel.x() >> shift) << shift, (voxel.y() >> shift) << shift,
                               (voxel.z() >> shift) << shift);
  return std::max(octant_exit(ray_v, corner, 1 << shift), t) +
         kExitNudge_voxels * map.voxel_size_m();
}

// What the march reads of the voxel nearest a sample.
struct NearestVoxel {
  bool observed;
  float tsdf;
};

template <typename VoxelT>
inline NearestVoxel nearest_voxel(const MarchBlock<VoxelT>& at, const Eigen::Vector3i& voxel) {
  const int side = block_scale_side(at.scale);
  const int index = ((voxel.x() & (kBlockSide - 1)) >> at.scale) +
                    ((voxel.y() & (kBlockSide - 1)) >> at.scale) * side +
                    ((voxel.z() & (kBlockSide - 1)) >> at.scale) * side * side;
  if (at.scale == 0) {
    const FinestVoxelT<VoxelT>& v = at.finest[index];
    return NearestVoxel{voxel_observed(v), voxel_tsdf(v)};
  }
  const VoxelT& v = at.level[index];
  return NearestVoxel{voxel_observed(v), voxel_tsdf(v)};
}

// A guided march's first voxel must be observed and in front of a surface. A coarse voxel's
// centre can lie behind the start by more than the margin: there the field at the start decides.
template <typename VoxelT>
inline bool start_in_front(const Octree<VoxelT>& map, const NearestVoxel& nearest,
                           const MarchBlock<VoxelT>& at, const Eigen::Vector3f& q,
                           BlockNeighbourhood<VoxelT>& neighbourhood) {
  bool accept = nearest.observed && nearest.tsdf > 0.0f;
  if (!accept && at.scale > 0) {
    TsdfSample at_start;
    accept = sample_tsdf_at_voxel_coords(map, q, at.block, neighbourhood, at_start) &&
             at_start.tsdf > 0.0f;
  }
  return accept;
}

// Far from the surface (an observed nearest voxel's value f_near above kFarTsdf): the step is
// that value less the distance to the voxel's centre, so it cannot pass further than the field
// says is free. False near the surface, and for NaN (corrupt voxels), which take the full sample.
inline bool far_step(float f_near, float cell_m, float mu_m, float& step) {
  step = f_near * mu_m - kNearestOffset_cells * cell_m;
  return f_near > kFarTsdf && step > cell_m;
}

// What the march remembers of the samples behind t.
struct MarchMemory {
  bool have_prev = false;     // prev_t and prev_f are the last sample's, just behind t
  bool prev_nearest = false;  // prev_f is a nearest-voxel read, not a trilinear sample
  float prev_t = 0.0f;
  float prev_f = 0.0f;
  TsdfSample prev_sample;  // the full sample at prev_t, when have_prev_sample
  bool have_prev_sample = false;
  // Samples failed at a thin-band scale after a positive one, which the prev_* values (not
  // have_prev) still hold: a negative sample within kBridge_mu of it closes the crossing.
  bool kept_prev = false;
  // Until a guided march takes a positive sample, a negative trilinear one means it started
  // behind the surface. Both flags are brought up to date where have_prev is dropped (a positive
  // prev ends confirm_start and is kept), not at every sample.
  bool confirm_start = false;

  bool positive_prev() const { return have_prev && prev_f > 0.0f; }
  void remember_nearest(float t, float f_near) {
    have_prev = true;
    prev_nearest = true;
    have_prev_sample = false;
    prev_t = t;
    prev_f = f_near;
  }
  void remember_sample(float t, const TsdfSample& sample) {
    have_prev = true;
    prev_nearest = false;
    prev_t = t;
    prev_f = sample.tsdf;
    prev_sample = sample;
    have_prev_sample = true;
  }
  // The ray crossed a free octant: nothing behind it is near the next sample.
  void forget_at_free_octant() {
    if (positive_prev()) confirm_start = false;
    have_prev = false;
    have_prev_sample = false;
    kept_prev = false;
  }
};

// The sample at q (`unobserved`: known to fail). At a thin-band scale, where a crossing is
// expected, a failed sample is read again from the cell's observed corners: the cell around a
// crossing often reaches a voxel the integrator never updated, or a block it never allocated.
template <typename VoxelT>
inline bool sample_near_surface(const Octree<VoxelT>& map, const Eigen::Vector3f& q,
                                const MarchBlock<VoxelT>& at, bool unobserved, int thin_scale,
                                const MarchMemory& memory,
                                BlockNeighbourhood<VoxelT>& neighbourhood, TsdfSample& sample) {
  // q is inside the cube and its block exists: the checked sample, inlined.
  bool sampled =
      !unobserved && detail::sample_tsdf_checked(map, q, *at.block, neighbourhood, sample);
  const bool thin = !sampled && at.scale >= thin_scale;
  if (thin && (memory.positive_prev() || memory.kept_prev || memory.confirm_start)) {
    sampled = sample_tsdf_observed_at_voxel_coords(map, q, at.block, kMinObservedWeight, sample);
  }
  return sampled;
}

// Moves t on past a failed sample (`thin`: at a thin-band scale); false when the step vanishes
// in float rounding.
inline bool step_past_failed_sample(MarchMemory& m, bool thin, float voxel_m, float mu_m,
                                    float& t) {
  // Past a positive sample the observed band behind a surface can be thinner than a coarse
  // step: back off towards the last good sample before giving up on it.
  if (m.positive_prev() && t - m.prev_t > kRetreatMin_voxels * voxel_m) {
    t = m.prev_t + 0.5f * (t - m.prev_t);
    return true;
  }
  // Unobserved space inside allocated blocks: a surface is only found inside an observed band,
  // whose positive side is mu thick, so half of mu cannot step over it.
  const float t_next = t + std::max(kUnobservedStep_mu * mu_m, voxel_m);
  if (!(t_next > t)) return false;
  // prev_* and have_prev_sample are left as they are: only have_prev says they are current.
  if (m.have_prev) {
    if (m.prev_f > 0.0f) m.confirm_start = false;
    m.kept_prev = thin && m.prev_f > 0.0f;
  }
  t = t_next;
  m.have_prev = false;
  return true;
}

// A negative sample f at t after failed ones: within kBridge_mu of the kept positive sample it
// closes the crossing with it (only unobserved samples lay between); at a thin-band scale it
// shows that a guided march started behind the surface (true: reject the march).
inline bool bridge_or_reject(MarchMemory& m, float t, float f, int scale, int thin_scale,
                             float mu_m) {
  if (!m.have_prev && f <= 0.0f && (m.kept_prev || m.confirm_start)) {
    if (m.kept_prev && t - m.prev_t <= kBridge_mu * mu_m) {
      m.have_prev = true;
    } else if (m.confirm_start && scale >= thin_scale) {
      return true;
    }
  }
  return false;
}

// The normal at q_hit from the gradient of at_hit's trilinear cell: no further samples. Central
// differences of the field at the hit's scale only where that gradient vanishes. False when
// neither gives a direction.
template <typename SampleAt>
bool surface_normal(const TsdfSample& at_hit, const Eigen::Vector3f& q_hit, SampleAt& sample_at,
                    Eigen::Vector3f& n_W) {
  const float h_voxels = static_cast<float>(1 << at_hit.scale);
  Eigen::Vector3f gradient = at_hit.gradient;
  Eigen::Vector3f central = Eigen::Vector3f::Zero();
  bool complete = !(gradient.squaredNorm() > 0.0f);
  for (int a = 0; a < 3 && complete; ++a) {
    Eigen::Vector3f offset = Eigen::Vector3f::Zero();
    offset[a] = h_voxels;
    TsdfSample plus;
    TsdfSample minus;
    complete = sample_at(q_hit + offset, plus) && sample_at(q_hit - offset, minus);
    central[a] = plus.tsdf - minus.tsdf;
  }
  if (complete && central.squaredNorm() > 0.0f) gradient = central;
  const float norm = gradient.norm();
  if (!(norm > 0.0f) || !std::isfinite(norm)) return false;
  n_W = gradient / norm;
  return true;
}

// The surface between the previous sample (positive) and `sample` at t (not positive); false when
// it has no normal.
template <typename VoxelT>
bool locate_hit(const Octree<VoxelT>& map, RowCache<VoxelT>& cache, const MarchBlock<VoxelT>& at,
                const Ray& ray, const VoxelRay& ray_v, float t, const TsdfSample& sample,
                MarchMemory& m, PixelHit& hit) {
  // By value: the march's state does not escape to the out-of-line samples.
  const VoxelBlock<VoxelT>* home = at.block;
  const Eigen::Vector3i home_coords = at.coords;
  auto sample_at = [&map, &cache, home, home_coords](const Eigen::Vector3f& q, TsdfSample& out) {
    return sample_field_at(map, cache, home, home_coords, q, out);
  };
  const float f = sample.tsdf;
  if (m.prev_nearest) {
    // Interpolate between two trilinear samples: take the full sample at the previous step.
    TsdfSample before;
    if (sample_at(ray_v.origin_v + m.prev_t * ray_v.dir_v, before) && before.tsdf > 0.0f) {
      m.prev_f = before.tsdf;
      m.prev_sample = before;
      m.have_prev_sample = true;
    }
  }
  // Zero crossing by linear interpolation between the last two samples.
  const float t_hit = m.prev_t + (t - m.prev_t) * m.prev_f / (m.prev_f - f);
  const Eigen::Vector3f q_hit = ray_v.origin_v + t_hit * ray_v.dir_v;
  // The normal and scale come from whichever of the two samples is nearer the surface: its
  // trilinear cell is at most a step from the hit, and a third sample would cost as much as the
  // two did.
  const TsdfSample& at_hit = m.have_prev_sample && m.prev_sample.tsdf < -f ? m.prev_sample : sample;
  Eigen::Vector3f n_W;
  if (!surface_normal(at_hit, q_hit, sample_at, n_W)) return false;
  hit.p_W = ray.origin_W + t_hit * ray.dir_W;
  hit.n_W = n_W;
  hit.scale = at_hit.scale;
  return true;
}

// Marches from t_start (>= t_near) to t_far. With `guided`, the first voxel of an allocated block
// the ray reaches must be observed and in front of a surface, and at a thin-band scale so must the
// first trilinear sample (a coarse voxel's centre can be in front of the surface while the start
// is behind it), or the march is rejected (also when it reads no voxel at all). Once accepted, no
// crossing after the start is a miss: a surface in front of the start is one the fused view did
// not see.
template <typename VoxelT>
MarchResult march(const Octree<VoxelT>& map, const RaycastConfig& config, const Ray& ray,
                  float t_near, float t_far, float t_start, bool guided, RowCache<VoxelT>& cache,
                  const VoxelRay& ray_v, std::uint64_t& steps_left, std::uint64_t& steps,
                  PixelHit& hit) {
  const float voxel_m = map.voxel_size_m();
  const int voxels_per_side = map.voxels_per_side();
  const float side_v = static_cast<float>(voxels_per_side);
  float t0 = t_near;
  float t1 = t_far;
  if (!clip_to_cube(ray_v, side_v, t0, t1)) return MarchResult::miss;

  // The step counters in registers, written back on every return (they are the caller's).
  struct StepTally {
    std::uint64_t& left_out;
    std::uint64_t& taken_out;
    std::uint64_t left;
    std::uint64_t taken;
    ~StepTally() {
      left_out = left;
      taken_out += taken;
    }
  } tally{steps_left, steps, steps_left, 0};

  float t = std::max(t0, t_start);
  // A guided march that never read a voxel proved nothing about its start.
  auto no_hit = [&guided] { return guided ? MarchResult::rejected : MarchResult::miss; };
  const int thin_scale = cache.thin_scale;
  MarchMemory memory;
  memory.confirm_start = guided;
  TsdfSample sample;
  MarchBlock<VoxelT> at;
  TreeCursor<VoxelT>& cursor = cache.cursor;
  BlockNeighbourhood<VoxelT>& neighbourhood = cache.neighbourhood;
  while (t <= t1) {
    if (tally.left == 0) return MarchResult::out_of_steps;
    --tally.left;
    ++tally.taken;
    const Eigen::Vector3f q = ray_v.origin_v + t * ray_v.dir_v;
    if (!inside_cube(q, side_v)) return no_hit();
    const Eigen::Vector3i voxel = q.cast<int>();
    enter_block(map, cursor, voxel, at);
    if (at.block == nullptr) {
      // Free octant: jump to its far face in one step.
      const float t_next = free_octant_exit(map, ray_v, voxel, at.where.level, t);
      // Far from the origin a step can vanish in float rounding: give up rather than spin.
      if (!(t_next > t)) return no_hit();
      t = t_next;
      memory.forget_at_free_octant();
      continue;
    }
    const NearestVoxel nearest = nearest_voxel(at, voxel);
    if (guided) {
      if (!start_in_front(map, nearest, at, q, neighbourhood)) return MarchResult::rejected;
      guided = false;
    }
    bool unobserved = false;  // the sample at q is known to fail
    if (nearest.observed) {
      const float f_near = nearest.tsdf;
      float step = 0.0f;
      if (far_step(f_near, voxel_m * static_cast<float>(1 << at.scale), config.mu_m, step)) {
        const float t_next = t + step;
        if (!(t_next > t)) return no_hit();
        memory.remember_nearest(t, f_near);
        t = t_next;
        continue;
      }
    } else {
      // The nearest voxel is one of the trilinear cell's corners: when the whole cell lies in
      // this block the sample fails without a look at the neighbours (exactly what it would
      // return), and only a cell across blocks may still be completed by a coarser neighbour.
      unobserved = cell_inside_block(*at.block, q, at.scale);
    }
    if (!sample_near_surface(map, q, at, unobserved, thin_scale, memory, neighbourhood, sample)) {
      if (!step_past_failed_sample(memory, at.scale >= thin_scale, voxel_m, config.mu_m, t)) {
        return no_hit();
      }
      continue;
    }
    const float f = sample.tsdf;
    if (bridge_or_reject(memory, t, f, sample.scale, thin_scale, config.mu_m)) {
      return MarchResult::rejected;
    }
    if (memory.positive_prev() && f <= 0.0f) {
      return locate_hit(map, cache, at, ray, ray_v, t, sample, memory, hit) ? MarchResult::hit
                                                                            : no_hit();
    }
    memory.remember_sample(t, sample);
    const float cell_m = voxel_m * static_cast<float>(1 << sample.scale);
    // Corrupt (non-finite) voxels make the step NaN; stop the ray then.
    const float t_next = t + std::max(f * config.mu_m, cell_m);
    if (!(t_next > t)) return no_hit();
    t = t_next;
  }
  return no_hit();
}

// Octants smaller than this are projected through their ancestor of at least this size: at 2 mm
// a block is 1.6 cm and there are too many of them to project every frame.
constexpr float kRangeOctantMin_m = 0.06f;
// Pads that keep the projected bounds conservative against float rounding.
constexpr float kRangePad_px = 1.0f;
constexpr float kRangePad_voxels = 1.0f;
// Octants reaching closer to the camera plane than this project unboundedly: they cover the image.
constexpr float kRangeMinCornerZ_m = 1e-3f;

// Widens the tile ranges with one octant [corner_W, corner_W + size_m]^3 (camera at T_C_W).
void add_octant_to_ranges(const Eigen::Vector3f& corner_W, float size_m,
                          const Eigen::Matrix3f& R_C_W, const Eigen::Vector3f& t_C_W,
                          const PinholeCamera& camera, float near_m, float far_m, float pad_m,
                          ImageView<TileDepthRange> ranges) {
  const Eigen::Vector3f c0_C = R_C_W * corner_W + t_C_W;
  // Corner i = corner + size * (bit 0: x, bit 1: y, bit 2: z); in the camera frame one
  // rotated edge vector per axis.
  const Eigen::Vector3f e_C[3] = {R_C_W.col(0) * size_m, R_C_W.col(1) * size_m,
                                  R_C_W.col(2) * size_m};
  float z_lo = std::numeric_limits<float>::max();
  float z_hi = -std::numeric_limits<float>::max();
  float u_lo = std::numeric_limits<float>::max();
  float u_hi = -std::numeric_limits<float>::max();
  float v_lo = u_lo;
  float v_hi = u_hi;
  bool unbounded = false;
  for (int i = 0; i < 8; ++i) {
    Eigen::Vector3f p_C = c0_C;
    if (i & 1) p_C += e_C[0];
    if (i & 2) p_C += e_C[1];
    if (i & 4) p_C += e_C[2];
    z_lo = std::min(z_lo, p_C.z());
    z_hi = std::max(z_hi, p_C.z());
    if (!(p_C.z() > kRangeMinCornerZ_m)) {
      unbounded = true;
      continue;
    }
    const Eigen::Vector2f px = camera.project(p_C);
    u_lo = std::min(u_lo, px.x());
    u_hi = std::max(u_hi, px.x());
    v_lo = std::min(v_lo, px.y());
    v_hi = std::max(v_hi, px.y());
  }
  // Depth is linear, so the corners bound the whole octant; NaN poses fail these tests.
  if (!(z_hi + pad_m >= near_m) || !(z_lo - pad_m <= far_m)) return;
  const int last_x = ranges.width - 1;
  const int last_y = ranges.height - 1;
  int tx0 = 0;
  int tx1 = last_x;
  int ty0 = 0;
  int ty1 = last_y;
  if (!unbounded) {
    // Pixel x lies in tile x / kRangeTile_px; the box of the projected corners holds the
    // projection of the whole (convex) octant.
    const float tile = static_cast<float>(kRangeTile_px);
    const float max_u = static_cast<float>(camera.width - 1);
    const float max_v = static_cast<float>(camera.height - 1);
    u_lo -= kRangePad_px;
    v_lo -= kRangePad_px;
    u_hi += kRangePad_px;
    v_hi += kRangePad_px;
    if (!(u_hi >= 0.0f && v_hi >= 0.0f && u_lo <= max_u && v_lo <= max_v)) return;
    tx0 = static_cast<int>(std::max(u_lo, 0.0f) / tile);
    ty0 = static_cast<int>(std::max(v_lo, 0.0f) / tile);
    tx1 = std::min(last_x, static_cast<int>(std::min(u_hi, max_u) / tile));
    ty1 = std::min(last_y, static_cast<int>(std::min(v_hi, max_v) / tile));
  }
  const float z_min = std::max(near_m, z_lo - pad_m);
  const float z_max = std::min(far_m, z_hi + pad_m);
  for (int ty = ty0; ty <= ty1; ++ty) {
    TileDepthRange* row = ranges.row(ty);
    for (int tx = tx0; tx <= tx1; ++tx) {
      TileDepthRange& r = row[tx];
      r.z_min_m = std::min(r.z_min_m, z_min);
      r.z_max_m = std::max(r.z_max_m, z_max);
    }
  }
}

// The depth-range image over every allocated octant (blocks, or the nodes kRangeOctantMin_m
// wide above them). Minima and maxima do not depend on the order, so neither does the result.
template <typename VoxelT>
void build_depth_ranges(const Octree<VoxelT>& map, const PinholeCamera& camera, const Se3d& T_W_C,
                        float near_m, float far_m, ImageView<TileDepthRange> ranges) {
  for (int y = 0; y < ranges.height; ++y) {
    for (int x = 0; x < ranges.width; ++x) ranges(x, y) = TileDepthRange{};
  }
  const Eigen::Matrix3f R_C_W = T_W_C.linear().transpose().cast<float>();
  const Eigen::Vector3f t_C_W = -(R_C_W * T_W_C.translation().cast<float>());
  const float voxel_m = map.voxel_size_m();
  const Eigen::Vector3f origin_W = map.config().origin_W;
  const float pad_m = kRangePad_voxels * voxel_m;
  int level = map.block_level();
  float size_m = map.config().block_size_m();
  while (size_m < kRangeOctantMin_m && level > 0) {
    --level;
    size_m *= 2.0f;
  }
  if (level == map.block_level()) {
    for (std::uint32_t i = 0; i < map.block_count(); ++i) {
      const Eigen::Vector3f corner_W =
          origin_W + map.block(i).min_voxel().template cast<float>() * voxel_m;
      add_octant_to_ranges(corner_W, size_m, R_C_W, t_C_W, camera, near_m, far_m, pad_m, ranges);
    }
    return;
  }
  for (std::uint32_t i = 0; i < map.node_count(); ++i) {
    const OctreeNode& node = map.node(i);
    if (node.level != level) continue;
    const Eigen::Vector3f corner_W =
        origin_W + key_corner_voxel(node.key()).template cast<float>() * voxel_m;
    add_octant_to_ranges(corner_W, size_m, R_C_W, t_C_W, camera, near_m, far_m, pad_m, ranges);
  }
}

// Rows per ray-casting task: enough to share cached voxels, few enough to balance two workers.
constexpr int kRowsPerTask = 8;

template <typename VoxelT>
struct RowJob {
  const Octree<VoxelT>* map;
  const RaycastConfig* config;
  const PinholeCamera* camera;
  Eigen::Matrix3f R_W_C;
  Eigen::Vector3f t_W_C;
  SurfaceMap surface_W;
  ImageView<std::uint8_t> scale;
  RaycastStats* row_stats;
  ImageView<const TileDepthRange> ranges;
  ImageView<const float> guide_depth_m;  // empty: no guide
  Eigen::Vector3f origin_v;              // the camera centre, where every ray starts, in voxels
  bool skip_repeated_misses;             // see kMissRetryPeriod
  std::uint32_t cast_index;

  // One task: kRowsPerTask consecutive rows, so a worker's cache keeps the voxels that
  // neighbouring rows share (rows dealt out one by one split them between the cores).
  void operator()(std::size_t task) const {
    RowCache<VoxelT> cache(*map, config->mu_m);
    const std::size_t end = std::min(static_cast<std::size_t>(config->height),
                                     (task + 1) * static_cast<std::size_t>(kRowsPerTask));
    for (std::size_t row = task * kRowsPerTask; row < end; ++row) march_row(row, cache);
  }

  // Marches pixel (x, y) into the outputs; true when the step budget left it invalid.
  bool march_pixel(int x, int y, RowCache<VoxelT>& cache, float voxel_m, std::uint64_t& steps_left,
                   RaycastStats& stats) const {
    ++stats.marched_pixels;
    // Read before it is overwritten: whether this pixel's ray hit in the previous cast.
    const bool missed_before = scale(x, y) == kNoScale;
    surface_W.vertices(x, y) = Eigen::Vector3f::Zero();
    surface_W.normals(x, y) = Eigen::Vector3f::Zero();
    scale(x, y) = kNoScale;
    if (steps_left == 0) {
      ++stats.budget_cut_pixels;
      return true;
    }
    const TileDepthRange& range = ranges(x / kRangeTile_px, y / kRangeTile_px);
    if (range.empty()) return false;  // nothing allocated along this ray
    const Eigen::Vector3f dir_C =
        camera->back_project(static_cast<float>(x), static_cast<float>(y), 1.0f);
    // Depth limits along z become distances along the unit ray.
    const float length = dir_C.norm();
    Ray ray{t_W_C, R_W_C * (dir_C / length)};
    VoxelRay ray_v;
    ray_v.origin_v = origin_v;
    ray_v.dir_v = ray.dir_W / voxel_m;
    for (int a = 0; a < 3; ++a) {
      ray_v.inv_dir_v[a] =
          ray_v.dir_v[a] != 0.0f ? 1.0f / ray_v.dir_v[a] : std::numeric_limits<float>::infinity();
    }
    const float t_near = range.z_min_m * length;
    const float t_far = range.z_max_m * length;
    // Start a guided ray in the band in front of the guide depth.
    float t_start = t_near;
    if (!guide_depth_m.empty()) {
      const float z_guide_m = guide_depth_m(x, y);
      // Also rejects NaN and no-data zeros.
      if (z_guide_m >= range.z_min_m && z_guide_m <= range.z_max_m) {
        t_start = z_guide_m * length - kGuideMargin_mu * config->mu_m;
      }
    }
    const bool guided = t_start > t_near;
    // Rays without a guide cost several times a guided one and mostly find nothing (regions
    // the sensor never measures: out of range, dark or shiny surfaces), so one that found
    // nothing last time waits for its turn.
    if (!guided && skip_repeated_misses && missed_before &&
        (static_cast<std::uint32_t>(x + y) + cast_index) % kMissRetryPeriod != 0) {
      ++stats.miss_skipped_pixels;
      return false;
    }
    PixelHit hit;
    MarchResult r = march(*map, *config, ray, t_near, t_far, t_start, guided, cache, ray_v,
                          steps_left, stats.steps, hit);
    if (guided) {
      ++stats.guided_pixels;
      if (r == MarchResult::rejected) {
        ++stats.guide_fallback_pixels;
        r = march(*map, *config, ray, t_near, t_far, t_near, false, cache, ray_v, steps_left,
                  stats.steps, hit);
      }
    }
    if (r == MarchResult::out_of_steps) {
      ++stats.budget_cut_pixels;
      return true;
    }
    if (r != MarchResult::hit) {
      if (guided) ++stats.guided_misses;
      return false;
    }
    // The hit must be in front of the camera (z > 0), a check a reference omitted.
    const Eigen::Vector3f p_C = R_W_C.transpose() * (hit.p_W - t_W_C);
    if (!(p_C.z() > 0.0f)) return false;
    surface_W.vertices(x, y) = hit.p_W;
    surface_W.normals(x, y) = hit.n_W;
    scale(x, y) = static_cast<std::uint8_t>(hit.scale);
    ++stats.valid_pixels;
    ++stats.scale_pixels[hit.scale];
    return false;
  }

  // Half resolution: an odd row copies the even row above it, which the same task marched just
  // before (tasks start at even rows), and so its counts.
  void copy_row_above(int y) const {
    const std::size_t width = static_cast<std::size_t>(config->width);
    std::memcpy(static_cast<void*>(surface_W.vertices.row(y)), surface_W.vertices.row(y - 1),
                width * sizeof(Eigen::Vector3f));
    std::memcpy(static_cast<void*>(surface_W.normals.row(y)), surface_W.normals.row(y - 1),
                width * sizeof(Eigen::Vector3f));
    std::memcpy(scale.row(y), scale.row(y - 1), width);
    const RaycastStats& above = row_stats[y - 1];
    RaycastStats& stats = row_stats[y];
    stats = RaycastStats{};
    stats.valid_pixels = above.valid_pixels;
    stats.budget_cut_pixels = above.budget_cut_pixels;
    for (int s = 0; s < 4; ++s) stats.scale_pixels[s] = above.scale_pixels[s];
  }

  void march_row(std::size_t row, RowCache<VoxelT>& cache) const {
    const int y = static_cast<int>(row);
    const int stride = config->pixel_stride;
    if (stride == 2 && (y & 1) != 0) {
      copy_row_above(y);
      return;
    }
    RaycastStats& stats = row_stats[row];
    stats = RaycastStats{};
    const std::uint64_t budget = config->step_budget;
    // The marched rows share the budget: every row, or the even ones at half resolution.
    const std::uint64_t rows = stride == 2 ? static_cast<std::uint64_t>(config->height + 1) / 2
                                           : static_cast<std::uint64_t>(config->height);
    const std::uint64_t share_index = row / static_cast<std::uint64_t>(stride);
    std::uint64_t steps_left = std::numeric_limits<std::uint64_t>::max();
    if (budget != 0) steps_left = budget / rows + (share_index < budget % rows ? 1u : 0u);
    const float voxel_m = map->voxel_size_m();
    Eigen::Vector3f* const vertex_row = surface_W.vertices.row(y);
    Eigen::Vector3f* const normal_row = surface_W.normals.row(y);
    std::uint8_t* const scale_row = scale.row(y);
    for (int x = 0; x < config->width; x += stride) {
      const bool cut = march_pixel(x, y, cache, voxel_m, steps_left, stats);
      if (stride == 2 && x + 1 < config->width) {
        // The right neighbour copies the marched pixel (as do its counts).
        std::memcpy(static_cast<void*>(vertex_row + x + 1), vertex_row + x, sizeof(*vertex_row));
        std::memcpy(static_cast<void*>(normal_row + x + 1), normal_row + x, sizeof(*normal_row));
        scale_row[x + 1] = scale_row[x];
        const std::uint8_t s = scale_row[x];
        if (s != kNoScale) {
          ++stats.valid_pixels;
          ++stats.scale_pixels[s];
        } else if (cut) {
          ++stats.budget_cut_pixels;
        }
      }
    }
  }
};

}  // namespace

Status validate(const RaycastConfig& config) {
  if (config.width <= 0 || config.height <= 0) return StatusCode::invalid_argument;
  if (!(config.near_m > 0.0f) || !(config.far_m > config.near_m) || !std::isfinite(config.far_m)) {
    return StatusCode::invalid_argument;
  }
  if (!(config.mu_m > 0.0f) || !std::isfinite(config.mu_m)) return StatusCode::invalid_argument;
  if (config.pixel_stride != 1 && config.pixel_stride != 2) return StatusCode::invalid_argument;
  return ok_status();
}

template <typename VoxelT>
Result<RaycastStats> Raycaster<VoxelT>::raycast(const Octree<VoxelT>& map,
                                                const PinholeCamera& camera, const Se3d& T_W_C,
                                                const WorkerTeam& team,
                                                ImageView<const float> guide_depth_m) {
  if (row_stats_ == nullptr || !map.reserved()) return StatusCode::failed_precondition;
  if (!camera.valid() || camera.width != config_.width || camera.height != config_.height) {
    return StatusCode::invalid_argument;
  }
  if (!guide_depth_m.empty() &&
      (guide_depth_m.width != config_.width || guide_depth_m.height != config_.height)) {
    return StatusCode::invalid_argument;
  }
  if (!T_W_C.matrix().allFinite()) return StatusCode::invalid_argument;
  build_depth_ranges(map, camera, T_W_C, config_.near_m, config_.far_m, ranges_);
  surface_W_.pixel_stride = config_.pixel_stride;
  RowJob<VoxelT> job{&map,
                     &config_,
                     &camera,
                     T_W_C.linear().cast<float>(),
                     T_W_C.translation().cast<float>(),
                     surface_W_,
                     scale_,
                     row_stats_,
                     ranges_,
                     guide_depth_m,
                     map.point_to_voxel_f(T_W_C.translation().cast<float>()),
                     !guide_depth_m.empty() && guided_casts_ > 0,
                     guided_casts_};
  if (!guide_depth_m.empty()) ++guided_casts_;
  const std::size_t tasks = (static_cast<std::size_t>(config_.height) + kRowsPerTask - 1) /
                            static_cast<std::size_t>(kRowsPerTask);
  team.for_each_task(tasks, job);
  RaycastStats total;
  for (int y = 0; y < config_.height; ++y) {
    const RaycastStats& row = row_stats_[y];
    total.steps += row.steps;
    total.valid_pixels += row.valid_pixels;
    total.budget_cut_pixels += row.budget_cut_pixels;
    total.marched_pixels += row.marched_pixels;
    total.guided_pixels += row.guided_pixels;
    total.guide_fallback_pixels += row.guide_fallback_pixels;
    total.miss_skipped_pixels += row.miss_skipped_pixels;
    total.guided_misses += row.guided_misses;
    for (int s = 0; s < 4; ++s) total.scale_pixels[s] += row.scale_pixels[s];
  }
  return total;
}

template class Raycaster<TsdfVoxel>;
template class Raycaster<MultiresVoxel>;
template class Raycaster<Multires16Voxel>;

}  // namespace octofuse
