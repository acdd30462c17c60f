// The distance reported for free points is a lower bound on the distance to the nearest surface,
// also where surfaces are hard to see: a floor seen at 80-88 degrees from its normal, thin boards
// seen at grazing angles, and 8 mm bars 3 m away, fused through the pipeline with exact depth and
// poses. The footprint's extra pixel on each side already catches a surface that runs on past an
// octant however steeply its depth changes between rays; the bars are thinner than the spacing of
// the rays there, so the frames whose rays all miss them carve through them (825 points over the
// bound, by up to 2.2 cm, before the distance was capped by the blocks that hold surfaces).

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include <catch2/catch.hpp>

#include "octofuse/pipeline/pipeline.hpp"
#include "support/aligned_buffer.hpp"
#include "support/analytic_scene.hpp"
#include "support/camera.hpp"

namespace octofuse {
namespace {

using test::AnalyticScene;

constexpr int kWidth = 320;
constexpr int kHeight = 240;
constexpr float kVoxel_m = 0.01f;
constexpr double kFloorY_m = 0.15;  // camera y points down: the floor is 15 cm below the camera
// Exact depth is stored in 0.2 mm units and the map in float: a bound this close is exact.
constexpr double kTolerance_m = 0.002;

Eigen::Matrix3d rotation(const Eigen::Vector3d& axis, double degrees) {
  return Eigen::AngleAxisd(degrees * 3.14159265358979 / 180.0, axis.normalized())
      .toRotationMatrix();
}

AnalyticScene grazing_scene() {
  AnalyticScene scene;
  // Normal towards the camera side, so that n . p - offset is the signed height above the floor.
  scene.planes.push_back({Eigen::Vector3d(0.0, -1.0, 0.0), -kFloorY_m});
  // A 6 mm board standing nearly edge-on to the view: its faces at about 84 degrees.
  scene.boxes.push_back({Eigen::Vector3d(0.35, -0.02, 1.8), Eigen::Vector3d(0.3, 0.12, 0.003),
                         rotation(Eigen::Vector3d::UnitY(), 84.0)});
  // Bars standing on the floor in front of a wall.
  scene.planes.push_back({Eigen::Vector3d(0.0, 0.0, -1.0), -3.8});
  for (int k = 0; k < 7; ++k) {
    scene.cylinders.push_back({Eigen::Vector3d(-0.6 + 0.2 * k + 0.013 * k * k, 0.0, 3.0 + 0.05 * k),
                               0.004, -0.4, kFloorY_m});
  }
  // A 6 mm shelf 5 cm below the camera, tilted 3 degrees: its top at 86-88 degrees.
  scene.boxes.push_back(
      {Eigen::Vector3d(-0.35, 0.05, 1.5), Eigen::Vector3d(0.25, 0.003, 0.25),
       rotation(Eigen::Vector3d::UnitX(), 3.0) * rotation(Eigen::Vector3d::UnitY(), 20.0)});
  return scene;
}

// Signed distance to the floor, the wall, the bars and the boards (negative inside).
double exact_distance(const AnalyticScene& scene, const Eigen::Vector3d& p) {
  double best = std::numeric_limits<double>::infinity();
  for (const AnalyticScene::Plane& plane : scene.planes) {
    best = std::min(best, plane.normal.dot(p) - plane.offset_m);
  }
  for (const AnalyticScene::CylinderY& c : scene.cylinders) {
    const double radial = std::hypot(p.x() - c.centre_W.x(), p.z() - c.centre_W.z()) - c.radius_m;
    const double axial = std::max(c.y_min_m - p.y(), p.y() - c.y_max_m);
    best = std::min(best, std::hypot(std::max(radial, 0.0), std::max(axial, 0.0)) +
                              std::min(std::max(radial, axial), 0.0));
  }
  for (const AnalyticScene::Box& box : scene.boxes) {
    const Eigen::Vector3d q = (box.R_W_B.transpose() * (p - box.centre_W)).cwiseAbs() - box.half_m;
    const double outside = q.cwiseMax(0.0).norm();
    const double inside = std::min(q.maxCoeff(), 0.0);
    best = std::min(best, outside + inside);
  }
  return best;
}

PinholeCamera input_camera() {
  return test::centred_camera(kWidth, kHeight, 262.5f);
}

struct Violations {
  long checked = 0;
  long free_points = 0;
  long over = 0;
  long within_voxel = 0;  // free within a voxel of a surface (or inside)
  double worst_m = -1.0;
  Eigen::Vector3d worst_point = Eigen::Vector3d::Zero();
  double worst_exact_m = 0.0;
  double worst_reported_m = 0.0;
};

void check_box(const MapQuery<MultiresVoxel>& query, const AnalyticScene& scene,
               const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, double step, Violations* v) {
  for (double z = lo.z(); z <= hi.z(); z += step) {
    for (double y = lo.y(); y <= hi.y(); y += step) {
      for (double x = lo.x(); x <= hi.x(); x += step) {
        const Eigen::Vector3d p(x, y, z);
        const PointAnswer a = query.point(p.cast<float>()).value();
        ++v->checked;
        if (a.state != PointState::free) continue;
        ++v->free_points;
        const double exact = exact_distance(scene, p);
        if (exact <= kVoxel_m) ++v->within_voxel;
        // A distance is not negative: inside an object it is checked against 0.
        const double excess = static_cast<double>(a.distance_m) - std::max(exact, 0.0);
        if (excess > kTolerance_m) ++v->over;
        if (excess > v->worst_m) {
          v->worst_m = excess;
          v->worst_point = p;
          v->worst_exact_m = exact;
          v->worst_reported_m = a.distance_m;
        }
      }
    }
  }
}

TEST_CASE("free distances stay lower bounds beside grazing surfaces and thin bars") {
  PipelineConfig config = default_pipeline_config(input_camera(), kVoxel_m, 9, 16384,
                                                  Eigen::Vector3f(0.0f, 0.0f, 2.2f));
  config.pose_source = PoseSource::ground_truth;
  REQUIRE(config.preprocess.downsample_factor == 2);
  const std::size_t bytes = bytes_required(config);
  REQUIRE(bytes > 0);
  test::Buffer buffer(bytes);
  Pipeline<MultiresVoxel> pipeline;
  REQUIRE(pipeline.init(buffer.data, bytes, config).ok());

  const AnalyticScene scene = grazing_scene();
  const PinholeCamera camera = input_camera();
  std::vector<float> depth;
  std::vector<std::uint16_t> raw(static_cast<std::size_t>(kWidth) * kHeight);
  constexpr int kFrames = 12;
  for (int i = 0; i < kFrames; ++i) {
    // Sideways and forwards with a little yaw, the camera's height kept: the floor stays grazing.
    const double s = static_cast<double>(i) / (kFrames - 1);
    Se3d T_W_C = Se3d::Identity();
    T_W_C.linear() = rotation(Eigen::Vector3d::UnitY(), -6.0 + 12.0 * s);
    T_W_C.translation() = Eigen::Vector3d(-0.2 + 0.4 * s, 0.01 * std::sin(5.0 * s), 0.25 * s);
    scene.render(camera, T_W_C, depth);
    for (std::size_t k = 0; k < raw.size(); ++k) {
      const double units = std::round(static_cast<double>(depth[k]) / 0.0002);
      raw[k] = units > 0.0 && units < 65535.0 ? static_cast<std::uint16_t>(units) : 0;
    }
    DepthFrame frame;
    frame.depth_raw = ImageView<const std::uint16_t>(raw.data(), kWidth, kHeight);
    frame.metres_per_unit = 0.0002f;
    frame.timestamp_us = 1000 + 33333 * i;
    frame.sequence = static_cast<std::uint64_t>(i);
    frame.has_ground_truth = true;
    frame.T_W_C_ground_truth = T_W_C.matrix();
    FrameStats stats;
    REQUIRE(pipeline.process(frame, &stats).ok());
  }

  const MapQuery<MultiresVoxel> query = pipeline.query();
  Violations v;
  // The air up to 30 cm over the floor, among the bars, and around each board.
  check_box(query, scene, Eigen::Vector3d(-1.2, kFloorY_m - 0.3, 0.4),
            Eigen::Vector3d(1.2, kFloorY_m - 0.005, 3.79), 0.01, &v);
  check_box(query, scene, Eigen::Vector3d(-0.8, -0.45, 2.7), Eigen::Vector3d(0.6, 0.1, 3.6), 0.01,
            &v);
  for (const AnalyticScene::Box& box : scene.boxes) {
    check_box(query, scene, box.centre_W - Eigen::Vector3d::Constant(0.45),
              box.centre_W + Eigen::Vector3d::Constant(0.45), 0.01, &v);
  }
  INFO("points " << v.checked << ", free " << v.free_points << ", over the bound " << v.over);
  // Free inside or within a voxel of a bar that the last frames missed: a state no distance
  // repairs.
  INFO("free within a voxel of a surface: " << v.within_voxel);
  INFO("worst: at " << v.worst_point.transpose() << " exact " << v.worst_exact_m << " m, reported "
                    << v.worst_reported_m << " m");
  // Enough free answers near the surfaces that the check means something.
  REQUIRE(v.free_points > 500000);
  REQUIRE(v.over == 0);
}

}  // namespace
}  // namespace octofuse
