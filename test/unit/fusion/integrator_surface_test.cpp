// Integration accuracy: planes and spheres fused at each scale cross zero where the surface is,
// the band behind a surface ends where configured, and the 16-bit voxel fuses like the float one.

#include "octofuse/fusion/integrator.hpp"

#include <catch2/catch.hpp>

#include "unit/fusion/integrator_support.hpp"

namespace octofuse {
namespace {

TEST_CASE("a plane fused at each scale crosses zero within a quarter voxel of it",
          "[fusion][integrator]") {
  constexpr double kPlaneZ_m = 1.237;
  constexpr float kVoxel_m = 0.01f;
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), kPlaneZ_m});
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  for (int scale = 0; scale <= kMaxBlockScale; ++scale) {
    CAPTURE(scale);
    Fusion<MultiresVoxel> fusion(map_config(kVoxel_m, 8, 8000), fusion_config(8 * kVoxel_m, scale),
                                 camera);
    for (int i = 0; i < 2; ++i) {
      const IntegrationReport r =
          fusion.fuse(scene, test::looking_along_z({0.01 * i, -0.02 * i, 0.1}));
      REQUIRE(r.status.ok());
      REQUIRE(r.blocks_integrated > 0);
      CHECK(r.blocks_per_scale[scale] == r.blocks_integrated);
    }
    const double kTolerance_m = 0.25 * kVoxel_m * (1 << scale);
    // Up-propagation is lazy (it stops at the frame's coarsest scale): complete it, as a coarse
    // query would, then read at the fused scale and every coarser one.
    for (std::uint32_t i = 0; i < fusion.map.block_count(); ++i) {
      VoxelBlock<MultiresVoxel>& b = fusion.map.block(i);
      if (b.integrated()) propagate_block_up(b, b.mip_scale, kMaxBlockScale);
    }
    for (int s = scale; s <= kMaxBlockScale; ++s) {
      for (const Eigen::Vector3i& column :
           {Eigen::Vector3i(128, 128, 0), Eigen::Vector3i(100, 150, 0),
            Eigen::Vector3i(150, 110, 0)}) {
        CAPTURE(s, column.transpose());
        const double z = zero_crossing_z(fusion.map, column, s, 0, 256);
        REQUIRE(std::isfinite(z));
        CHECK(std::abs(z - kPlaneZ_m) <= 0.25 * kVoxel_m * (1 << s));
      }
    }
    (void)kTolerance_m;
  }
}

TEMPLATE_TEST_CASE(
    "a shorter band behind the surface stops at behind_mu * mu, the values unchanged",
    "[fusion][integrator]", TsdfVoxel, MultiresVoxel) {
  // mu = 8 voxels at 1 cm, a plane head-on at scale 0: with behind_mu 3/8 voxels up to 3 cm
  // behind it are updated, with their full-band values; deeper ones are not observed. In front
  // nothing changes.
  constexpr double kPlaneZ_m = 1.237;
  constexpr float kVoxel_m = 0.01f;
  constexpr float kMu_m = 8.0f * kVoxel_m;
  constexpr double kMargin_m = 0.001;
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), kPlaneZ_m});
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  FusionConfig full_config = fusion_config(kMu_m, 0);
  FusionConfig short_config = full_config;
  short_config.behind_mu = 0.375f;
  Fusion<TestType> full(map_config(kVoxel_m, 8, 8000), full_config, camera);
  Fusion<TestType> cut(map_config(kVoxel_m, 8, 8000), short_config, camera);
  const Se3d T_W_C = test::looking_along_z({0.0, 0.0, 0.1});
  REQUIRE(full.fuse(scene, T_W_C).status.ok());
  REQUIRE(cut.fuse(scene, T_W_C).status.ok());
  int in_front = 0;
  int behind_kept = 0;
  int behind_cut = 0;
  for (int z = 0; z < 256; ++z) {
    const Eigen::Vector3i column(128, 128, z);
    TestType read_a;
    TestType read_b;
    if (!full.map.read_voxel(column, 0, &read_a) || !cut.map.read_voxel(column, 0, &read_b)) {
      continue;
    }
    const TestType* a = &read_a;
    const TestType* b = &read_b;
    const double behind_plane_m = full.map.voxel_centre_W(column, 0).z() - kPlaneZ_m;
    if (!voxel_observed(*a)) continue;
    CAPTURE(z, behind_plane_m);
    if (behind_plane_m > 0.375 * kMu_m + kMargin_m) {
      CHECK_FALSE(voxel_observed(*b));
      ++behind_cut;
    } else {
      REQUIRE(voxel_observed(*b));
      CHECK(voxel_tsdf(*b) == voxel_tsdf(*a));
      ++(behind_plane_m > 0.0 ? behind_kept : in_front);
    }
  }
  CHECK(in_front >= 7);
  CHECK(behind_kept >= 3);
  CHECK(behind_cut >= 4);
}

TEST_CASE("where mu is under 2.5 voxels of the scale, voxels 2.5 voxels behind are observed",
          "[fusion][integrator]") {
  // mu = 1.5 voxels at 1 cm: at scale 0 the band reaches 2.5 voxels behind the plane instead of
  // 1.5, at scale s 2.5 * 2^s voxels; past mu the value is -1. The blocks are those of the band
  // +- mu.
  constexpr double kPlaneZ_m = 1.237;
  constexpr float kVoxel_m = 0.01f;
  constexpr float kMu_m = 1.5f * kVoxel_m;
  constexpr double kMargin_m = 0.001;  // keeps voxel centres clear of the thresholds
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), kPlaneZ_m});
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  for (int scale = 0; scale <= kMaxBlockScale; ++scale) {
    CAPTURE(scale);
    Fusion<MultiresVoxel> fusion(map_config(kVoxel_m, 8, 8000), fusion_config(kMu_m, scale),
                                 camera);
    REQUIRE(fusion.fuse(scene, test::looking_along_z({0.0, 0.0, 0.1})).status.ok());
    const double cell_m = kVoxel_m * (1 << scale);
    const double behind_m = std::max<double>(kMu_m, 2.5 * cell_m);
    int observed_past_mu = 0;
    // The column through the optical axis, where distances along the ray are along z.
    for (int z = 0; z < 256; z += 1 << scale) {
      const Eigen::Vector3i column(128, 128, z);
      MultiresVoxel read;
      if (!fusion.map.read_voxel(column, scale, &read)) continue;  // not in the band's blocks
      const MultiresVoxel* v = &read;
      const double behind_plane_m = fusion.map.voxel_centre_W(column, scale).z() - kPlaneZ_m;
      CAPTURE(z, behind_plane_m);
      if (behind_plane_m > behind_m + kMargin_m) {
        CHECK_FALSE(voxel_observed(*v));
      } else if (behind_plane_m > kMu_m + kMargin_m) {
        REQUIRE(voxel_observed(*v));
        CHECK(voxel_tsdf(*v) == -1.0f);
        ++observed_past_mu;
      } else if (behind_plane_m > -kMu_m) {
        REQUIRE(voxel_observed(*v));
        CHECK(voxel_tsdf(*v) == Approx(-behind_plane_m / kMu_m).margin(1e-3));
      }
    }
    // Each scale's band has voxels past mu in the blocks: the check above saw some.
    CHECK(observed_past_mu > 0);
  }
}

TEST_CASE("single-resolution fusion of a plane crosses zero within a quarter voxel",
          "[fusion][integrator]") {
  constexpr double kPlaneZ_m = 1.161;
  constexpr float kVoxel_m = 0.01f;
  constexpr double kTolerance_m = 0.25 * kVoxel_m;
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), kPlaneZ_m});
  Fusion<TsdfVoxel> fusion(map_config(kVoxel_m, 8, 8000), fusion_config(8 * kVoxel_m),
                           test::centred_camera(160, 120, 131.0f));
  const IntegrationReport r = fusion.fuse(scene, test::looking_along_z({0, 0, 0.2}));
  REQUIRE(r.status.ok());
  CHECK(r.blocks_per_scale[0] == r.blocks_integrated);
  CHECK(r.blocks_allocated == r.blocks_requested);
  CHECK(r.voxels_updated > 0);
  for (int x = 100; x < 160; x += 7) {
    const double z = zero_crossing_z(fusion.map, Eigen::Vector3i(x, 128, 0), 0, 0, 256);
    REQUIRE(std::isfinite(z));
    CHECK(std::abs(z - kPlaneZ_m) <= kTolerance_m);
  }
}

TEST_CASE("a sphere fused at each scale crosses zero within a quarter voxel of it",
          "[fusion][integrator]") {
  constexpr float kVoxel_m = 0.01f;
  const Eigen::Vector3d centre(0.003, -0.002, 1.5);
  constexpr double kRadius_m = 0.3;
  AnalyticScene scene;
  scene.spheres.push_back({centre, kRadius_m});
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  for (int scale = 0; scale <= kMaxBlockScale; ++scale) {
    CAPTURE(scale);
    Fusion<MultiresVoxel> fusion(map_config(kVoxel_m, 8, 8000), fusion_config(8 * kVoxel_m, scale),
                                 camera);
    for (int i = 0; i < 2; ++i) {
      REQUIRE(fusion.fuse(scene, test::looking_along_z({0.02 * i, 0.0, 0.2})).status.ok());
    }
    const double kTolerance_m = 0.25 * kVoxel_m * (1 << scale);
    // Columns near the sphere's axis, facing the camera.
    for (const Eigen::Vector3i& column :
         {Eigen::Vector3i(128, 128, 0), Eigen::Vector3i(136, 120, 0),
          Eigen::Vector3i(120, 136, 0)}) {
      const Eigen::Vector3f c = fusion.map.voxel_centre_W(column, scale);
      const double dx = c.x() - centre.x();
      const double dy = c.y() - centre.y();
      const double truth = centre.z() - std::sqrt(kRadius_m * kRadius_m - dx * dx - dy * dy);
      const double z = zero_crossing_z(fusion.map, column, scale, 0, 256);
      CAPTURE(column.transpose(), truth, z);
      REQUIRE(std::isfinite(z));
      CHECK(std::abs(z - truth) <= kTolerance_m);
    }
  }
}

// Multires16Voxel against MultiresVoxel, same frames at a fixed scale. Each update rounds to the
// nearest 2^-14 step, at most half a step h = 2^-15 off; the float mean forgets an old error by
// y / (y + 1) per sample, so after n samples the two differ by at most (n + 1) / 2 * h (plus float
// rounding, far below). Mip levels (means of children, rounded once more) add h per level.
// Across a plane the normalised TSDF falls by 1 / mu per metre, so a TSDF error e moves the
// interpolated zero crossing by about e * mu.
TEST_CASE("the 16-bit voxel fuses like the float one within its quantisation bound",
          "[fusion][integrator][multires16]") {
  constexpr float kVoxel_m = 0.01f;
  constexpr float kMu_m = 8 * kVoxel_m;
  constexpr int kFrames = 12;
  constexpr double kHalfStep = 1.0 / 32768.0;
  constexpr double kFloatSlack = 1e-6;  // float rounding of the two running means
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), 1.237});
  scene.spheres.push_back({Eigen::Vector3d(0.2, 0.1, 1.0), 0.15});
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  for (int scale = 0; scale <= 1; ++scale) {
    CAPTURE(scale);
    Fusion<MultiresVoxel> ref(map_config(kVoxel_m, 8, 8000), fusion_config(kMu_m, scale), camera);
    Fusion<Multires16Voxel> q16(map_config(kVoxel_m, 8, 8000), fusion_config(kMu_m, scale), camera);
    for (int i = 0; i < kFrames; ++i) {
      // A small sideways sweep: every voxel sees samples that differ from frame to frame.
      const Se3d pose = test::looking_along_z({0.004 * i, -0.003 * i, 0.1 + 0.002 * i});
      const IntegrationReport a = ref.fuse(scene, pose);
      const IntegrationReport b = q16.fuse(scene, pose);
      REQUIRE(a.status.ok());
      REQUIRE(b.status.ok());
      REQUIRE(a.voxels_updated == b.voxels_updated);
    }
    REQUIRE(ref.map.block_count() == q16.map.block_count());
    const double voxel_bound = (kFrames + 1) / 2.0 * kHalfStep + kFloatSlack;
    double worst = 0.0;
    std::uint64_t compared = 0;
    for (std::uint32_t i = 0; i < ref.map.block_count(); ++i) {
      const VoxelBlock<MultiresVoxel>& a = ref.map.block(i);
      const VoxelBlock<Multires16Voxel>& b = q16.map.block(i);
      REQUIRE(a.coords == b.coords);
      if (!a.integrated()) continue;
      for (int k = 0; k < block_scale_count(scale); ++k) {
        const MultiresVoxel va = a.voxel(block_scale_offset(scale) + k);
        const Multires16Voxel vb = b.voxel(block_scale_offset(scale) + k);
        // Whole sample counts: the weights are exact.
        REQUIRE(voxel_weight(vb) == voxel_weight(va));
        REQUIRE(voxel_delta_y(vb) == voxel_delta_y(va));
        if (!voxel_observed(va)) continue;
        worst = std::max(worst, std::abs(double{voxel_tsdf(vb)} - voxel_tsdf(va)));
        ++compared;
      }
    }
    CAPTURE(worst, voxel_bound);
    CHECK(compared > 10000);
    CHECK(worst <= voxel_bound);
    CHECK(worst > 0.0);  // the two really differ: the bound is what is tested
    // The plane's zero crossing, at the fused scale and one mip level up (completing the lazy
    // up-propagation first, as a coarse query would).
    for (std::uint32_t i = 0; i < ref.map.block_count(); ++i) {
      VoxelBlock<MultiresVoxel>& a = ref.map.block(i);
      VoxelBlock<Multires16Voxel>& b = q16.map.block(i);
      if (a.integrated()) propagate_block_up(a, a.mip_scale, kMaxBlockScale);
      if (b.integrated()) propagate_block_up(b, b.mip_scale, kMaxBlockScale);
    }
    for (int s = scale; s <= scale + 1; ++s) {
      const double bound_m = (voxel_bound + (s - scale) * kHalfStep) * kMu_m;
      for (const Eigen::Vector3i& column :
           {Eigen::Vector3i(100, 100, 0), Eigen::Vector3i(96, 150, 0),
            Eigen::Vector3i(150, 90, 0)}) {
        CAPTURE(s, column.transpose());
        const double za = zero_crossing_z(ref.map, column, s, 0, 256);
        const double zb = zero_crossing_z(q16.map, column, s, 0, 256);
        REQUIRE(std::isfinite(za));
        REQUIRE(std::isfinite(zb));
        CHECK(std::abs(za - 1.237) <= 0.25 * kVoxel_m * (1 << s));
        CHECK(std::abs(zb - za) <= bound_m);
      }
    }
  }
}

}  // namespace
}  // namespace octofuse
