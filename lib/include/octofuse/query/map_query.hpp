#pragma once
// What a planner asks of the map: the state of a point, and whether a box, a sphere or a sphere
// swept along a segment (the robot's body over one path step) is free.
//
// Sources, in order of precedence at a point:
//   1. outside the cube: `outside`;
//   2. a block whose TSDF was integrated at or after the last frame that saw the point's free
//      octant free (FreeSpace): the TSDF decides. Interpolated |tsdf| < 1: `near`, with the
//      signed distance (metres) and its gradient; -1 (more than mu behind a surface): `inside`
//      (with FusionConfig::behind_mu < 1 the band ends sooner, and deeper points read unknown).
//      The TSDF holds distances along camera rays, longer than the Euclidean ones on slanted
//      surfaces by the gradient's length, so the distance is divided by that when it exceeds 1;
//      it stays an estimate (thin objects seen from one side read negative behind them), not a
//      bound: collision checks use the region queries. +1 (more than mu in front along the
//      camera rays): `free` when a free octant holds the point, else `unknown`;
//   3. a free octant: `free` (also over a block integrated before that frame: the object there
//      has gone);
//   4. otherwise `unknown`. Unknown is never free.
// For `free` the distance is a lower bound on the distance to the nearest surface seen: the
// free-space margin plus the distance to the free octant's faces (0 when only the TSDF says
// free: the projective TSDF bounds no Euclidean distance), but no more than the distance to the
// nearest block holding an observed voxel at or behind a surface (grown by a voxel of its scale):
// a frame whose rays all pass beside an object thinner than their spacing (a bar a few mm across,
// metres away) carves through it, and that octant is newer than the object's blocks.
//
// Regions (box, sphere, swept sphere) are `free` only when every part is: a walk over the free
// octree visits the octants the shape touches (a leaf's free halves count where the shape touches
// no other half); free octants are free unless a block inside was
// integrated after them, whose voxels are then read. A voxel the shape touches is `blocked` when
// it is observed and its signed distance is within its half-diagonal plus one finest voxel (a
// surface may lie in it), or it is behind a surface; otherwise it is free inside a free octant
// and `unknown` elsewhere (as are parts outside the cube). Blocked wins over unknown.
//
// Work per call: a point query walks at most voxel_depth free-octree levels and reads the 8
// voxels of one trilinear cell (and their blocks); a free one also walks the TSDF octree's nodes
// within its distance bound. A region query visits free octants, blocks and
// voxels, counting each as one unit; at QueryLimits::max_visits it stops and answers `unknown`
// with budget_hit set, so that limit is the worst case (default 2^16 units; a 0.5 m box in the sim
// scenes took up to 50 000).
// Nothing allocates. With a MapGuard every call holds it shared for its duration.

#include <cstdint>

#include <Eigen/Core>

#include "octofuse/core/result.hpp"
#include "octofuse/map/octree.hpp"
#include "octofuse/query/free_space.hpp"
#include "octofuse/query/map_guard.hpp"

namespace octofuse {

enum class PointState : std::uint8_t { outside, unknown, free, near, inside };
// "outside", "unknown", "free", "near", "inside".
const char* point_state_name(PointState state);

enum class RegionState : std::uint8_t { free, blocked, unknown };
// "free", "blocked", "unknown".
const char* region_state_name(RegionState state);

struct PointAnswer {
  PointState state = PointState::unknown;
  // near: interpolated signed distance (m, negative behind the surface); inside: -mu (at least
  // that far behind); free: lower bound on the distance to the nearest surface (0: none known);
  // outside, unknown: 0.
  float distance_m = 0.0f;
  // near, when all 8 neighbours were observed: gradient of the signed distance (about unit
  // length, pointing away from the surface). Zero otherwise.
  Eigen::Vector3f gradient = Eigen::Vector3f::Zero();
  bool has_gradient = false;
  std::uint64_t map_version = 0;  // map updates (frames) the answer reflects
};

struct RegionAnswer {
  RegionState state = RegionState::unknown;
  std::uint32_t visits = 0;  // free octants, blocks and voxels visited
  bool budget_hit = false;   // stopped at max_visits (then state is unknown)
  std::uint64_t map_version = 0;
};

struct QueryLimits {
  std::uint32_t max_visits = 1u << 16;
};

template <typename VoxelT>
class MapQuery {
 public:
  // `free_space` may be null (then nothing is known free but what the TSDF says); `guard` and
  // `version` may be null (single-threaded use). All must outlive the MapQuery.
  MapQuery(const Octree<VoxelT>& map, const FreeSpace* free_space, float mu_m,
           const MapGuard* guard = nullptr, const std::uint64_t* version = nullptr)
      : map_(&map), free_(free_space), mu_m_(mu_m), guard_(guard), version_(version) {}

  const Octree<VoxelT>& map() const { return *map_; }
  const FreeSpace* free_space() const { return free_; }
  float mu_m() const { return mu_m_; }

  // invalid_argument for a non-finite point.
  Result<PointAnswer> point(const Eigen::Vector3f& p_W) const;
  // invalid_argument: a non-finite corner or min > max on some axis, or max_visits 0.
  Result<RegionAnswer> box(const Eigen::Vector3f& min_W, const Eigen::Vector3f& max_W,
                           const QueryLimits& limits = QueryLimits()) const;
  // invalid_argument: a non-finite centre or radius, or a negative radius.
  Result<RegionAnswer> sphere(const Eigen::Vector3f& centre_W, float radius_m,
                              const QueryLimits& limits = QueryLimits()) const;
  // The sphere swept from a_W to b_W (a capsule). invalid_argument as sphere().
  Result<RegionAnswer> swept_sphere(const Eigen::Vector3f& a_W, const Eigen::Vector3f& b_W,
                                    float radius_m,
                                    const QueryLimits& limits = QueryLimits()) const;

 private:
  struct Shape;
  PointAnswer point_unguarded(const Eigen::Vector3f& p_W) const;
  // min(limit, distance from q to the nearest block that may hold a surface), in finest voxels
  // (cube coordinates).
  float surface_clearance_voxels(const Eigen::Vector3f& q, float limit) const;
  RegionAnswer region(const Shape& shape, const QueryLimits& limits) const;

  const Octree<VoxelT>* map_;
  const FreeSpace* free_;
  float mu_m_;
  const MapGuard* guard_;
  const std::uint64_t* version_;
};

extern template class MapQuery<TsdfVoxel>;
extern template class MapQuery<MultiresVoxel>;
extern template class MapQuery<Multires16Voxel>;

}  // namespace octofuse
