#pragma once
// Reconstruction quality of a mesh against a ground-truth scene given as a signed distance
// function (the sim port provides one). Accuracy: how far the mesh vertices lie from the true
// surface, |sdf(vertex)|. Completeness: the fraction of ground-truth surface samples that have a
// mesh vertex within a threshold (nearest-vertex queries through a uniform grid hash).

#include <cstddef>
#include <vector>

#include <Eigen/Core>

#include "octofuse/ports/host/host_buffer.hpp"
#include "octofuse/ports/host/ply.hpp"

namespace octofuse::host {

// Signed distance in metres from `p_W` to the true surface (sign does not matter here).
using SignedDistanceFn = double (*)(const Eigen::Vector3d& p_W, const void* context);

struct MeshAccuracy {
  std::size_t vertices = 0;
  double rmse_m = 0.0;
  double mean_m = 0.0;
  double max_m = 0.0;
};
MeshAccuracy mesh_accuracy(const MeshView& mesh, SignedDistanceFn sdf, const void* context);

struct MeshCompleteness {
  std::size_t samples = 0;
  std::size_t covered = 0;  // samples with a vertex within threshold_m
  double fraction = 0.0;    // covered / samples (0 for no samples)
};
// threshold_m > 0.
MeshCompleteness mesh_completeness(const MeshView& mesh,
                                   const std::vector<Eigen::Vector3d>& surface_samples_W,
                                   double threshold_m);

// Finds, for query points, whether any of a fixed set of points lies within a radius. Cells of
// side `radius`, so a query looks at its own and the 26 neighbouring cells.
class PointGridHash {
 public:
  PointGridHash(const Eigen::Vector3f* points, std::size_t count, double radius_m);
  bool any_within(const Eigen::Vector3d& query) const;
  // Distance to the nearest point if within the radius, else a negative value.
  double nearest_within(const Eigen::Vector3d& query) const;

 private:
  std::size_t bucket(long long x, long long y, long long z) const;

  const Eigen::Vector3f* points_;
  double radius_m_;
  HostBuffer<std::size_t>
      bucket_start_;  // CSR: points of bucket b are order_[start[b], start[b+1])
  HostBuffer<std::size_t> order_;
  HostBuffer<long long> cell_;  // cell coordinates, 3 per point, to filter hash collisions
};

}  // namespace octofuse::host
