#include "octofuse/ports/host/mesh_eval.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <random>

using octofuse::host::MeshView;

namespace {

constexpr double kTolerance_m = 1e-6;  // float vertices

struct Sphere {
  Eigen::Vector3d centre;
  double radius_m;
};

double sphere_sdf(const Eigen::Vector3d& p_W, const void* context) {
  const Sphere& s = *static_cast<const Sphere*>(context);
  return (p_W - s.centre).norm() - s.radius_m;
}

}  // namespace

TEST_CASE("mesh accuracy is the statistics of |sdf| at the vertices", "[host][mesh_eval]") {
  const Sphere sphere{{0.5, -0.2, 1.0}, 0.25};
  // Vertices off the sphere by known distances: +1 cm, -2 cm, 0, +3 cm.
  const double offsets[4] = {0.01, -0.02, 0.0, 0.03};
  const Eigen::Vector3d directions[4] = {{1, 0, 0}, {0, 1, 0}, {0, 0, -1}, {0.6, 0.0, 0.8}};
  std::vector<Eigen::Vector3f> vertices;
  for (int i = 0; i < 4; ++i) {
    vertices.push_back(
        (sphere.centre + directions[i] * (sphere.radius_m + offsets[i])).cast<float>());
  }
  MeshView mesh;
  mesh.vertices = vertices.data();
  mesh.vertex_count = vertices.size();
  const auto accuracy = octofuse::host::mesh_accuracy(mesh, &sphere_sdf, &sphere);
  CHECK(accuracy.vertices == 4);
  CHECK(accuracy.mean_m == Approx(0.015).margin(kTolerance_m));
  CHECK(accuracy.rmse_m == Approx(std::sqrt((1e-4 + 4e-4 + 9e-4) / 4.0)).margin(kTolerance_m));
  CHECK(accuracy.max_m == Approx(0.03).margin(kTolerance_m));
}

TEST_CASE("mesh completeness counts samples with a vertex within the threshold",
          "[host][mesh_eval]") {
  constexpr double kThreshold_m = 0.01;
  // Vertices on a 10 cm lattice; 60 samples sit 5 mm from a vertex, 40 sit 2 cm away (and at
  // least 8 cm from any other vertex).
  std::vector<Eigen::Vector3f> vertices;
  for (int i = 0; i < 100; ++i) {
    vertices.emplace_back(0.1f * static_cast<float>(i % 10), 0.1f * static_cast<float>(i / 10),
                          1.0f);
  }
  std::vector<Eigen::Vector3d> samples;
  for (int i = 0; i < 100; ++i) {
    const double offset_m = i < 60 ? 0.5 * kThreshold_m : 2.0 * kThreshold_m;
    samples.push_back(vertices[i].cast<double>() + Eigen::Vector3d(0, 0, offset_m));
  }
  MeshView mesh;
  mesh.vertices = vertices.data();
  mesh.vertex_count = vertices.size();
  const auto completeness = octofuse::host::mesh_completeness(mesh, samples, kThreshold_m);
  CHECK(completeness.samples == 100);
  CHECK(completeness.covered == 60);
  CHECK(completeness.fraction == Approx(0.6));
}

TEST_CASE("grid hash nearest-within agrees with brute force", "[host][mesh_eval]") {
  constexpr double kRadius_m = 0.05;
  std::mt19937 rng(42);
  std::uniform_real_distribution<float> uniform(-0.5f, 0.5f);
  std::vector<Eigen::Vector3f> points(2000);
  for (auto& p : points) p = Eigen::Vector3f(uniform(rng), uniform(rng), uniform(rng));
  const octofuse::host::PointGridHash grid(points.data(), points.size(), kRadius_m);
  int within = 0;
  for (int q = 0; q < 500; ++q) {
    const Eigen::Vector3d query(uniform(rng), uniform(rng), uniform(rng));
    double best = 1e9;
    for (const auto& p : points) best = std::min(best, (p.cast<double>() - query).norm());
    const double found = grid.nearest_within(query);
    if (best <= kRadius_m) {
      ++within;
      CHECK(found == Approx(best).margin(1e-12));
    } else {
      CHECK(found < 0.0);
    }
  }
  CHECK(within > 100);  // the test exercises both branches
}

TEST_CASE("empty mesh gives zero accuracy and completeness", "[host][mesh_eval]") {
  MeshView mesh;
  const Sphere sphere{{0, 0, 0}, 1.0};
  CHECK(octofuse::host::mesh_accuracy(mesh, &sphere_sdf, &sphere).rmse_m == 0.0);
  const auto completeness =
      octofuse::host::mesh_completeness(mesh, {Eigen::Vector3d(0, 0, 1)}, 0.01);
  CHECK(completeness.covered == 0);
  CHECK(completeness.fraction == 0.0);
}
