#pragma once
// What a planner asks of the map: the state of a point, and whether a box, a sphere or a sphere
// swept along a segment (the robot's body over one path step) is free. The TSDF and the free
// space answer together; unknown is never free. lib/README.md ("Queries") gives the order of
// precedence, the distance bound of free answers and the work per call (bounded by
// QueryLimits::max_visits). Nothing allocates. With a MapGuard every call holds it shared for
// its duration.

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
