#include "octofuse/ports/host/mesh_eval.hpp"

#include <algorithm>
#include <cmath>

#include "octofuse/core/check.hpp"

namespace octofuse::host {
namespace {

long long cell_of(double coordinate, double cell_m) {
  return static_cast<long long>(std::floor(coordinate / cell_m));
}

}  // namespace

MeshAccuracy mesh_accuracy(const MeshView& mesh, SignedDistanceFn sdf, const void* context) {
  MeshAccuracy result;
  double sum = 0.0, sum_sq = 0.0;
  for (std::size_t i = 0; i < mesh.vertex_count; ++i) {
    const double d = std::fabs(sdf(mesh.vertices[i].cast<double>(), context));
    sum += d;
    sum_sq += d * d;
    result.max_m = std::max(result.max_m, d);
  }
  result.vertices = mesh.vertex_count;
  if (mesh.vertex_count > 0) {
    const double n = static_cast<double>(mesh.vertex_count);
    result.mean_m = sum / n;
    result.rmse_m = std::sqrt(sum_sq / n);
  }
  return result;
}

MeshCompleteness mesh_completeness(const MeshView& mesh,
                                   const std::vector<Eigen::Vector3d>& surface_samples_W,
                                   double threshold_m) {
  OCTOFUSE_CHECK(threshold_m > 0.0);
  const PointGridHash grid(mesh.vertices, mesh.vertex_count, threshold_m);
  MeshCompleteness result;
  result.samples = surface_samples_W.size();
  for (const Eigen::Vector3d& sample : surface_samples_W) {
    if (grid.any_within(sample)) ++result.covered;
  }
  if (result.samples > 0) {
    result.fraction = static_cast<double>(result.covered) / static_cast<double>(result.samples);
  }
  return result;
}

PointGridHash::PointGridHash(const Eigen::Vector3f* points, std::size_t count, double radius_m)
    : points_(points), radius_m_(radius_m) {
  OCTOFUSE_CHECK(radius_m > 0.0);
  // About one bucket per point keeps chains short without a huge table.
  const std::size_t buckets = std::max<std::size_t>(1, count);
  bucket_start_.resize(buckets + 1);
  cell_.resize(3 * count);
  HostBuffer<std::size_t> point_bucket;
  point_bucket.resize(count);
  for (std::size_t i = 0; i < count; ++i) {
    for (int k = 0; k < 3; ++k) cell_[3 * i + k] = cell_of(points[i][k], radius_m);
    point_bucket[i] = bucket(cell_[3 * i], cell_[3 * i + 1], cell_[3 * i + 2]);
    ++bucket_start_[point_bucket[i] + 1];
  }
  for (std::size_t b = 0; b < buckets; ++b) bucket_start_[b + 1] += bucket_start_[b];
  order_.resize(count);
  HostBuffer<std::size_t> fill;
  fill.resize(buckets);
  for (std::size_t b = 0; b < buckets; ++b) fill[b] = bucket_start_[b];
  for (std::size_t i = 0; i < count; ++i) order_[fill[point_bucket[i]]++] = i;
}

std::size_t PointGridHash::bucket(long long x, long long y, long long z) const {
  // The usual spatial hash primes (Teschner et al. 2003).
  const unsigned long long h = static_cast<unsigned long long>(x) * 73856093ull ^
                               static_cast<unsigned long long>(y) * 19349663ull ^
                               static_cast<unsigned long long>(z) * 83492791ull;
  return static_cast<std::size_t>(h % (bucket_start_.size() - 1));
}

double PointGridHash::nearest_within(const Eigen::Vector3d& query) const {
  const long long cx = cell_of(query.x(), radius_m_);
  const long long cy = cell_of(query.y(), radius_m_);
  const long long cz = cell_of(query.z(), radius_m_);
  double best_sq = radius_m_ * radius_m_;
  bool found = false;
  for (long long dz = -1; dz <= 1; ++dz) {
    for (long long dy = -1; dy <= 1; ++dy) {
      for (long long dx = -1; dx <= 1; ++dx) {
        const std::size_t b = bucket(cx + dx, cy + dy, cz + dz);
        for (std::size_t k = bucket_start_[b]; k < bucket_start_[b + 1]; ++k) {
          const std::size_t i = order_[k];
          // Skip hash collisions from other cells (they are checked with their own cell).
          if (cell_[3 * i] != cx + dx || cell_[3 * i + 1] != cy + dy ||
              cell_[3 * i + 2] != cz + dz) {
            continue;
          }
          const double d_sq = (points_[i].cast<double>() - query).squaredNorm();
          if (d_sq <= best_sq) {
            best_sq = d_sq;
            found = true;
          }
        }
      }
    }
  }
  return found ? std::sqrt(best_sq) : -1.0;
}

bool PointGridHash::any_within(const Eigen::Vector3d& query) const {
  return nearest_within(query) >= 0.0;
}

}  // namespace octofuse::host
