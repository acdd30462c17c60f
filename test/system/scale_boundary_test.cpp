// Holes at coarse scales: at 2 mm voxels the multires map holds blocks at scales 1, 2 and 3
// (4, 8 and 16 mm voxels) side by side in one view of the desk, and the truncation band
// (mu = 1.6 cm) is only a few voxels thick at the coarse ones. Every pixel with fused depth whose
// ray meets the fused surface must still get a ray-cast vertex, on the analytic surface.

#include <algorithm>
#include <catch2/catch.hpp>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "octofuse/pipeline/pipeline.hpp"
#include "octofuse/ports/sim/sim_source.hpp"
#include "support/aligned_buffer.hpp"
#include "support/alloc_counter.hpp"
#include "support/small_sim.hpp"

namespace octofuse {
namespace {

constexpr float kVoxel_m = 0.002f;
constexpr int kVoxelDepth = 11;  // a 4 m cube
constexpr std::uint32_t kBlocks = 40000;
// The first half of a 20-frame pass over the desk: from over the keyboard (scales 1 and 2) back
// to where the floor and the far wall integrate at scale 3.
constexpr int kPathFrames = 20;
constexpr int kFrames = 10;
// A pixel next to a depth jump larger than this (a silhouette, a thin part) may look past what
// the band fused around it: its ray need not meet the fused surface.
constexpr float kEdgeJump_m = 0.01f;
// Vertex against the analytic surface, along the ray, in voxels of the vertex's scale: all within
// kMaxError_cells, and no more than kMaxFarShare of them beyond one voxel (the trilinear field
// rounds the desk's box corners by up to a couple of voxels).
constexpr float kMaxError_cells = 3.0f;
constexpr double kMaxFarShare = 0.01;
// Horizontal neighbours with vertices of different scales in every frame: the boundaries the
// check runs across.
constexpr int kMinScalePairs = 50;

struct Coverage {
  int checked = 0;           // pixels with fused depth, away from depth jumps and the near plane
  int empty = 0;             // of those, without a vertex
  int far = 0;               // of those with a vertex, more than a voxel of its scale off
  float worst_cells = 0.0f;  // largest error, in voxels of the vertex's scale
  int scale_pixels[kMaxBlockScale + 1] = {};  // checked pixels with a vertex, per scale
  int scale_pairs = 0;  // horizontal neighbours both with a vertex, at different scales
};

// Compares the last ray-cast (from the frame's own pose) with the frame's exact depth.
Coverage measure(const Pipeline<MultiresVoxel>& pipeline, const DepthFrame& frame,
                 ImageView<const float> exact_depth_m) {
  Coverage c;
  const PinholeCamera& camera = pipeline.working_camera();
  const ConstSurfaceMap surface = pipeline.surface_W();
  const ImageView<const std::uint8_t> scale = pipeline.scale_image();
  const Eigen::Isometry3f T_C_W = pipeline.T_W_C().inverse().cast<float>();
  const float near_m = pipeline.config().fusion.near_m;
  const float far_m = pipeline.config().fusion.far_m;
  const float mu_m = pipeline.config().fusion.mu_m;
  auto fused = [&](int x, int y) {
    const float z_m = static_cast<float>(frame.depth_raw(x, y)) * frame.metres_per_unit;
    return frame.depth_raw(x, y) != 0 && z_m >= near_m && z_m <= far_m;
  };
  for (int y = 1; y + 1 < camera.height; ++y) {
    for (int x = 1; x + 1 < camera.width; ++x) {
      if (surface.valid(x, y) && surface.valid(x + 1, y) && scale(x, y) != scale(x + 1, y)) {
        ++c.scale_pairs;
      }
      if (!fused(x, y)) continue;
      const float z_m = exact_depth_m(x, y);
      // Within mu of the near plane the ray starts inside the band, past its positive side.
      bool skip = z_m < near_m + mu_m;
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          skip = skip || !fused(x + dx, y + dy) ||
                 !(std::fabs(exact_depth_m(x + dx, y + dy) - z_m) <= kEdgeJump_m);
        }
      }
      if (skip) continue;
      ++c.checked;
      if (!surface.valid(x, y)) {
        ++c.empty;
        continue;
      }
      const int s = scale(x, y);
      ++c.scale_pixels[s];
      const Eigen::Vector3f p_C = T_C_W * surface.vertices(x, y);
      const float ray_per_z =
          camera.back_project(static_cast<float>(x), static_cast<float>(y), 1.0f).norm();
      const float error_cells =
          std::fabs(p_C.z() - z_m) * ray_per_z / (kVoxel_m * static_cast<float>(1 << s));
      c.worst_cells = std::max(c.worst_cells, error_cells);
      if (error_cells > 1.0f) ++c.far;
    }
  }
  return c;
}

// Whether two ray-casts are the same, bit for bit.
bool same_surface(const ConstSurfaceMap& a, const ConstSurfaceMap& b) {
  for (int y = 0; y < a.height(); ++y) {
    for (int x = 0; x < a.width(); ++x) {
      if (std::memcmp(a.vertices(x, y).data(), b.vertices(x, y).data(), sizeof(float) * 3) != 0 ||
          std::memcmp(a.normals(x, y).data(), b.normals(x, y).data(), sizeof(float) * 3) != 0) {
        return false;
      }
    }
  }
  return true;
}

TEST_CASE("at 2 mm every pixel with fused depth gets a vertex on the surface, across scales") {
  sim::SimSource source(test::small_sim(kPathFrames, /*noise=*/false));
  REQUIRE(source.open().ok());
  const Se3d T_W_C0 = source.ground_truth_T_W_C(0);
  PipelineConfig config =
      default_pipeline_config(source.intrinsics(), kVoxel_m, kVoxelDepth, kBlocks,
                              (T_W_C0.translation() + T_W_C0.linear().col(2)).cast<float>());
  config.preprocess.downsample_factor = 1;  // the exact depth is the working depth
  config.pose_source = PoseSource::ground_truth;
  config.free_space.enabled = false;
  config.budget.raycast_half = false;  // every pixel of the guided reference cast is checked
  // The same frames through a pipeline with 3 workers give the same ray-cast.
  PipelineConfig config3 = config;
  config3.workers = 3;
  test::Buffer buffer(bytes_required(config));
  test::Buffer buffer3(bytes_required(config3));
  Pipeline<MultiresVoxel> pipeline;
  Pipeline<MultiresVoxel> pipeline3;
  REQUIRE(pipeline.init(buffer.data, bytes_required(config), config).ok());
  REQUIRE(pipeline3.init(buffer3.data, bytes_required(config3), config3).ok());
  int scale_pixels[kMaxBlockScale + 1] = {};
  DepthFrame frame;
  for (int i = 0; i < kFrames; ++i) {
    CAPTURE(i);
    REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
    FrameStats stats;
    FrameStats stats3;
    {
      const test::AllocationScope scope;
      REQUIRE(pipeline.process(frame, &stats).ok());
      REQUIRE(pipeline3.process(frame, &stats3).ok());
      // No frame allocates, the ray-cast's thin-band paths included.
      REQUIRE(scope.allocations() == 0);
    }
    REQUIRE(stats.integration.pool_refusals == 0);
    REQUIRE(same_surface(pipeline.surface_W(), pipeline3.surface_W()));
    const Coverage c = measure(pipeline, frame, source.last_exact_depth_m());
    CAPTURE(c.checked, c.scale_pixels[1], c.scale_pixels[2], c.scale_pixels[3], c.scale_pairs);
    REQUIRE(c.checked > test::kSmallSimWidth * test::kSmallSimHeight / 3);
    CHECK(c.scale_pairs >= kMinScalePairs);
    CHECK(c.empty == 0);
    CHECK(c.worst_cells <= kMaxError_cells);
    CHECK(static_cast<double>(c.far) <= kMaxFarShare * static_cast<double>(c.checked));
    for (int s = 0; s <= kMaxBlockScale; ++s) scale_pixels[s] += c.scale_pixels[s];
  }
  // Scales 1, 2 and 3 all came back from the ray-cast.
  CHECK(scale_pixels[1] > 0);
  CHECK(scale_pixels[2] > 0);
  CHECK(scale_pixels[3] > 0);
}

}  // namespace
}  // namespace octofuse
