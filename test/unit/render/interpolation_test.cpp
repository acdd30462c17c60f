#include "octofuse/render/interpolation.hpp"

#include <catch2/catch.hpp>
#include <cmath>

#include "unit/render/analytic_map.hpp"

namespace octofuse {
namespace {

constexpr float kVoxel_m = 0.01f;
constexpr float kMu_m = 0.1f;
constexpr float kTolerance = 1e-4f;  // normalised TSDF

MapConfig small_config() {
  MapConfig config;
  config.voxel_size_m = kVoxel_m;
  config.voxel_depth = 6;  // 0.64 m cube
  config.origin_W = Eigen::Vector3f::Zero();
  config.block_capacity = 512;
  config.node_capacity = 512;
  return config;
}

// A linear field is reproduced exactly by trilinear interpolation on any grid.
const Eigen::Vector3f kSlope(0.3f, -0.2f, 0.5f);
float linear_sdf(const Eigen::Vector3f& p_W) {
  return kSlope.dot(p_W - Eigen::Vector3f(0.3f, 0.3f, 0.3f));
}

// Fills every block of the 8^3-block cube.
template <typename ScaleOf>
void fill_all(Octree<MultiresVoxel>& map, const ScaleOf& scale_of) {
  for (int z = 0; z < 8; ++z) {
    for (int y = 0; y < 8; ++y) {
      for (int x = 0; x < 8; ++x) {
        Result<std::uint32_t> b = map.allocate_block({x, y, z});
        REQUIRE(b.ok());
        test::fill_block(map, map.block(b.value()), scale_of(Eigen::Vector3i(x, y, z)), kMu_m,
                         linear_sdf);
      }
    }
  }
}

TEST_CASE("samples a linear field exactly at the block's scale, with its gradient") {
  const int scale = GENERATE(0, 1, 2, 3);
  test::OwnedMap<MultiresVoxel> owned(small_config());
  fill_all(owned.map, [scale](const Eigen::Vector3i&) { return scale; });
  const Eigen::Vector3f p_W(0.2913f, 0.3107f, 0.2871f);
  TsdfSample sample;
  REQUIRE(sample_tsdf(owned.map, p_W, sample));
  REQUIRE(sample.scale == scale);
  REQUIRE(sample.tsdf == Approx(linear_sdf(p_W) / kMu_m).margin(kTolerance));
  const Eigen::Vector3f expected_gradient = kSlope / kMu_m;
  REQUIRE((sample.gradient - expected_gradient).norm() < 1e-2f);
}

TEST_CASE("a coarser neighbour moves the sample to the common coarser grid (Fig. 5)") {
  test::OwnedMap<MultiresVoxel> owned(small_config());
  // Block x < 4 at scale 0, x >= 4 at scale 2: the seam is at x = 0.32 m.
  fill_all(owned.map, [](const Eigen::Vector3i& b) { return b.x() < 4 ? 0 : 2; });
  TsdfSample sample;
  // Well inside the fine side.
  REQUIRE(sample_tsdf(owned.map, Eigen::Vector3f(0.25f, 0.3f, 0.3f), sample));
  REQUIRE(sample.scale == 0);
  // Just left of the seam: a neighbour lies in a scale-2 block.
  const Eigen::Vector3f seam_W(0.318f, 0.3f, 0.3f);
  REQUIRE(sample_tsdf(owned.map, seam_W, sample));
  REQUIRE(sample.scale == 2);
  REQUIRE(sample.tsdf == Approx(linear_sdf(seam_W) / kMu_m).margin(kTolerance));
  // On the coarse side.
  REQUIRE(sample_tsdf(owned.map, Eigen::Vector3f(0.4f, 0.3f, 0.3f), sample));
  REQUIRE(sample.scale == 2);
}

TEST_CASE("no sample outside the map, in missing blocks or unobserved voxels") {
  test::OwnedMap<MultiresVoxel> owned(small_config());
  TsdfSample sample;
  REQUIRE_FALSE(sample_tsdf(owned.map, Eigen::Vector3f(0.3f, 0.3f, 0.3f), sample));
  REQUIRE_FALSE(sample_tsdf(owned.map, Eigen::Vector3f(-1.0f, 0.3f, 0.3f), sample));
  REQUIRE_FALSE(sample_tsdf(owned.map, Eigen::Vector3f(NAN, 0.3f, 0.3f), sample));
  // An allocated but never integrated block.
  REQUIRE(owned.map.allocate_block({3, 3, 3}).ok());
  REQUIRE_FALSE(sample_tsdf(owned.map, Eigen::Vector3f(0.28f, 0.28f, 0.28f), sample));
}

}  // namespace
}  // namespace octofuse
