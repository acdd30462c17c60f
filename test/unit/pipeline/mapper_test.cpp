// Mapper and MapperSettings (pipeline/mapper.hpp): the settings give the reference config, the
// mapper reserves everything in init() and allocates nothing while it maps and meshes.
#include "octofuse/pipeline/mapper.hpp"

#include <catch2/catch.hpp>
#include <cstdint>
#include <vector>

#include "support/alloc_counter.hpp"

namespace octofuse {
namespace {

constexpr int kWidth = 160;
constexpr int kHeight = 120;

PinholeCamera small_camera() {
  PinholeCamera camera;
  camera.fx = camera.fy = 525.0f / 4.0f;
  camera.cx = (kWidth - 1) * 0.5f;
  camera.cy = (kHeight - 1) * 0.5f;
  camera.width = kWidth;
  camera.height = kHeight;
  return camera;
}

// A wall facing the camera 1.5 m ahead, every pixel measured.
struct Wall {
  std::vector<std::uint16_t> raw = std::vector<std::uint16_t>(kWidth * kHeight, 1500);
  DepthFrame frame(int i) const {
    DepthFrame frame;
    frame.depth_raw = ImageView<const std::uint16_t>(raw.data(), kWidth, kHeight);
    frame.metres_per_unit = 0.001f;
    frame.timestamp_us = 1000 + 33333 * i;
    frame.sequence = static_cast<std::uint64_t>(i);
    frame.has_ground_truth = true;  // the identity: the camera stays where it started
    return frame;
  }
};

TEST_CASE("the default settings are the reference config around the first camera") {
  const PinholeCamera camera = small_camera();
  MapperSettings settings;
  settings.first_T_W_C.translation() = Eigen::Vector3d(0.5, -0.25, 2.0);
  const PipelineConfig config = pipeline_config(camera, settings);
  const Eigen::Vector3f centre_W(0.5f, -0.25f, 3.5f);
  const PipelineConfig reference = default_pipeline_config(camera, 0.02f, 8, 40000, centre_W);
  CHECK(config.map.voxel_depth == 8);
  CHECK(config.map.voxel_size_m == reference.map.voxel_size_m);
  CHECK(config.map.origin_W == reference.map.origin_W);
  CHECK(config.map.block_capacity == 40000);
  CHECK(bytes_required(config) == bytes_required(reference));
  CHECK(config.initial_T_W_C.translation() == settings.first_T_W_C.translation());
  CHECK(config.initial_pose_from_ground_truth);
  CHECK(config.workers == 1);
  CHECK(config.free_space.enabled);

  settings.map_size_m = 5.13f;  // one voxel depth more
  settings.threads = 2;
  settings.use_ground_truth_pose = false;
  const PipelineConfig bigger = pipeline_config(camera, settings);
  CHECK(bigger.map.voxel_depth == 9);
  CHECK(bigger.workers == 2);
  CHECK_FALSE(bigger.initial_pose_from_ground_truth);
}

TEST_CASE("a mapper maps and meshes with the memory it reserved in init") {
  // At the frames' true poses (a flat wall leaves ICP nothing to hold on to).
  PipelineConfig config = pipeline_config(small_camera(), MapperSettings());
  config.pose_source = PoseSource::ground_truth;
  Mapper<> mapper;
  REQUIRE(mapper.init(config, 1u << 16, 1u << 17).ok());
  CHECK(mapper.bytes_reserved() >= bytes_required(config));
  const Wall wall;
  FrameStats stats;
  FrameResult results[3];
  bool processed = true;
  test::AllocationScope scope;
  for (int i = 0; i < 3; ++i) {
    processed = processed && mapper.process(wall.frame(i), &stats).ok();
    results[i] = stats.result;
  }
  const Result<const MeshBuffer*> mesh = mapper.extract_mesh();
  const std::uint64_t allocations = scope.allocations();
  CHECK(allocations == 0);
  REQUIRE(processed);
  CHECK(results[0] == FrameResult::first);
  CHECK(results[2] == FrameResult::tracked);
  REQUIRE(mesh.ok());
  CHECK(mesh.value()->triangles().size() > 100);
  for (const MeshVertex& vertex : mesh.value()->vertices()) {
    CHECK(vertex.p_W.z() == Approx(1.5f).margin(0.02f));
  }
  const Result<PointAnswer> at_wall = mapper.query().point(Eigen::Vector3f(0.0f, 0.0f, 1.5f));
  REQUIRE(at_wall.ok());
  CHECK(at_wall.value().state == PointState::near);
  CHECK(mapper.init(small_camera()).code() == StatusCode::failed_precondition);
}

TEST_CASE("bad settings and a mesh beyond its capacity are refused with a reason") {
  MapperSettings settings;
  settings.voxel_size_m = 0.0f;
  Mapper<> bad;
  CHECK(bad.init(small_camera(), settings).code() == StatusCode::invalid_argument);
  CHECK(std::string(bad.last_error()) != "");

  settings = MapperSettings();
  settings.mesh_vertex_capacity = 0;
  Mapper<> no_mesh;
  REQUIRE(no_mesh.init(small_camera(), settings).ok());
  CHECK(no_mesh.extract_mesh().status().code() == StatusCode::failed_precondition);

  settings.mesh_vertex_capacity = 16;
  settings.mesh_triangle_capacity = 16;
  Mapper<TsdfVoxel> small_mesh;
  REQUIRE(small_mesh.init(small_camera(), settings).ok());
  const Wall wall;
  FrameStats stats;
  REQUIRE(small_mesh.process(wall.frame(0), &stats).ok());
  CHECK(small_mesh.extract_mesh().status().code() == StatusCode::resource_exhausted);
  CHECK(std::string(small_mesh.last_error()).find("meshing stopped") != std::string::npos);
}

}  // namespace
}  // namespace octofuse
