#include "octofuse/map/interpolation.hpp"

#include <catch2/catch.hpp>
#include <cmath>

#include "support/analytic_map.hpp"

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

// The normalised field at the centre of a finest voxel, as fill_block writes it.
float voxel_value(const Eigen::Vector3i& voxel) {
  return linear_sdf((voxel.cast<float>() + Eigen::Vector3f::Constant(0.5f)) * kVoxel_m) / kMu_m;
}

// Trilinear weight of corner c (bit 0: x, 1: y, 2: z) at fractions `frac`.
float corner_weight(int c, const Eigen::Vector3f& frac) {
  return ((c & 1) != 0 ? frac.x() : 1.0f - frac.x()) * ((c & 2) != 0 ? frac.y() : 1.0f - frac.y()) *
         ((c & 4) != 0 ? frac.z() : 1.0f - frac.z());
}

TEST_CASE("a cell with unobserved corners is sampled from its observed ones, by their weights") {
  test::OwnedMap<MultiresVoxel> owned(small_config());
  fill_all(owned.map, [](const Eigen::Vector3i&) { return 0; });
  // q = p / voxel: the cell's corners are voxels (27..28, 29..30, 29..30), all in block (3, 3, 3)
  // near the field's zero, at fractions (0.8, 0.1, 0.7) of it.
  const Eigen::Vector3f q(28.3f, 29.6f, 30.2f);
  const Eigen::Vector3i base(27, 29, 29);
  const Eigen::Vector3f frac = q - Eigen::Vector3f::Constant(0.5f) - base.cast<float>();
  const VoxelBlock<MultiresVoxel>* home = owned.map.find_block({3, 3, 3});
  REQUIRE(home != nullptr);
  BlockNeighbourhood<MultiresVoxel> neighbourhood;
  TsdfSample full;
  TsdfSample observed;
  // All observed: the full sample, value and gradient.
  REQUIRE(sample_tsdf_at_voxel_coords(owned.map, q, home, neighbourhood, full));
  REQUIRE(sample_tsdf_observed_at_voxel_coords(owned.map, q, home, 1.0f, observed));
  REQUIRE(observed.tsdf == Approx(full.tsdf).margin(kTolerance));
  REQUIRE((observed.gradient - full.gradient).norm() < 1e-3f);
  REQUIRE(observed.scale == 0);

  auto corner = [&](int c) -> Eigen::Vector3i {
    return base + Eigen::Vector3i(c & 1, (c >> 1) & 1, (c >> 2) & 1);
  };
  auto unobserve = [&](int c) {
    const Eigen::Vector3i v = corner(c);
    test::set_block_voxel(*owned.map.find_block_at_voxel(v),
                          block_voxel_index(v.x() & 7, v.y() & 7, v.z() & 7, 0), 0.0f, 0.0f);
  };
  // Corner 7 unobserved: the full sample fails; the others' weighted mean, weight 0.944.
  unobserve(7);
  REQUIRE_FALSE(sample_tsdf_at_voxel_coords(owned.map, q, home, neighbourhood, full));
  float sum = 0.0f;
  float weight = 0.0f;
  for (int c = 0; c < 7; ++c) {
    sum += corner_weight(c, frac) * voxel_value(corner(c));
    weight += corner_weight(c, frac);
  }
  REQUIRE(weight == Approx(0.944f));
  REQUIRE(sample_tsdf_observed_at_voxel_coords(owned.map, q, home, 0.9f, observed));
  REQUIRE(observed.tsdf == Approx(sum / weight).margin(kTolerance));
  REQUIRE(observed.gradient.allFinite());
  REQUIRE_FALSE(sample_tsdf_observed_at_voxel_coords(owned.map, q, home, 0.95f, observed));

  // Only corner 0 left (weight 0.2 * 0.9 * 0.3 = 0.054): its value, when that much is enough.
  for (int c = 1; c < 7; ++c) unobserve(c);
  REQUIRE_FALSE(sample_tsdf_observed_at_voxel_coords(owned.map, q, home, 0.25f, observed));
  REQUIRE(sample_tsdf_observed_at_voxel_coords(owned.map, q, home, 0.05f, observed));
  REQUIRE(observed.tsdf == Approx(voxel_value(corner(0))).margin(kTolerance));
  // Nothing observed: no sample, whatever the threshold.
  unobserve(0);
  REQUIRE_FALSE(sample_tsdf_observed_at_voxel_coords(owned.map, q, home, 1e-6f, observed));
}

TEST_CASE("corners in a block never allocated count as unobserved") {
  test::OwnedMap<MultiresVoxel> owned(small_config());
  Result<std::uint32_t> b = owned.map.allocate_block({3, 3, 3});
  REQUIRE(b.ok());
  test::fill_block(owned.map, owned.map.block(b.value()), 0, kMu_m, linear_sdf);
  // Corners x = 31 (block 3) and x = 32 (block 4, not allocated), fractions (0.7, 0.5, 0.5).
  const Eigen::Vector3f q(32.2f, 28.0f, 28.0f);
  const VoxelBlock<MultiresVoxel>* home = &owned.map.block(b.value());
  BlockNeighbourhood<MultiresVoxel> neighbourhood;
  TsdfSample sample;
  REQUIRE_FALSE(sample_tsdf_at_voxel_coords(owned.map, q, home, neighbourhood, sample));
  // The x = 31 face carries 0.3 of the weight; on it the field is linear, so the sample is the
  // field at (31.5, 28, 28) voxels.
  REQUIRE_FALSE(sample_tsdf_observed_at_voxel_coords(owned.map, q, home, 0.5f, sample));
  REQUIRE(sample_tsdf_observed_at_voxel_coords(owned.map, q, home, 0.25f, sample));
  const Eigen::Vector3f face_W = Eigen::Vector3f(31.5f, 28.0f, 28.0f) * kVoxel_m;
  REQUIRE(sample.tsdf == Approx(linear_sdf(face_W) / kMu_m).margin(kTolerance));
  // Outside the cube or NaN: no sample.
  REQUIRE_FALSE(sample_tsdf_observed_at_voxel_coords(owned.map, Eigen::Vector3f(NAN, 28.0f, 28.0f),
                                                     home, 0.25f, sample));
  REQUIRE_FALSE(sample_tsdf_observed_at_voxel_coords(
      owned.map, Eigen::Vector3f(-5.0f, 28.0f, 28.0f), home, 0.25f, sample));
}

}  // namespace
}  // namespace octofuse
