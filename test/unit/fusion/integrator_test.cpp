#include "octofuse/fusion/integrator.hpp"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <memory>
#include <vector>

#include <catch2/catch.hpp>

#include "octofuse/map/mip.hpp"
#include "support/aligned_buffer.hpp"
#include "support/alloc_counter.hpp"
#include "support/analytic_scene.hpp"
#include "support/camera.hpp"

namespace octofuse {
namespace {

using test::AnalyticScene;

// A map and an integrator over one arena, sized by bytes_required.
template <typename VoxelT>
struct Fusion {
  Fusion(const MapConfig& map_config, const FusionConfig& fusion_config, const PinholeCamera& cam)
      : camera(cam),
        buffer(Octree<VoxelT>::bytes_required(map_config) +
               Integrator<VoxelT>::bytes_required(fusion_config, cam.width, cam.height)) {
    REQUIRE(map.reserve(buffer.arena(), map_config).ok());
    REQUIRE(integrator.reserve(buffer.arena(), fusion_config, cam.width, cam.height).ok());
    REQUIRE(buffer.arena().bytes_used() == buffer.bytes());
  }

  IntegrationReport fuse(const AnalyticScene& scene, const Se3d& T_W_C,
                         const FusionBudget& budget = FusionBudget(), int workers = 1) {
    scene.render(camera, T_W_C, depth);
    WorkerTeam team(workers);
    return fuse_rendered(T_W_C, budget, team);
  }
  IntegrationReport fuse_rendered(const Se3d& T_W_C, const FusionBudget& budget,
                                  const WorkerTeam& team) {
    ImageView<const float> view(depth.data(), camera.width, camera.height);
    return integrator.integrate(map, view, camera, T_W_C, frame++, budget, team);
  }

  PinholeCamera camera;
  test::ArenaBuffer buffer;
  Octree<VoxelT> map;
  Integrator<VoxelT> integrator;
  std::vector<float> depth;
  std::uint32_t frame = 0;
};

MapConfig map_config(float voxel_size_m, int depth, std::uint32_t blocks) {
  return MapConfig::centred(Eigen::Vector3f(0.0f, 0.0f, 1.0f), voxel_size_m, depth, blocks, blocks);
}

FusionConfig fusion_config(float mu_m, int fixed_scale = -1) {
  FusionConfig c;
  c.mu_m = mu_m;
  c.fixed_scale = fixed_scale;
  c.max_blocks_per_frame = 1u << 15;
  c.far_m = 6.0f;
  return c;
}

// Zero crossing (front to back, + to -) along world z at the voxel column through finest voxel
// `column` at `scale`, by linear interpolation between voxel centres; NaN when there is none.
template <typename VoxelT>
double zero_crossing_z(const Octree<VoxelT>& map, Eigen::Vector3i column, int scale, int z_begin,
                       int z_end) {
  const int step = 1 << scale;
  const VoxelT* previous = nullptr;
  double previous_z = 0.0;
  for (int z = z_begin; z < z_end; z += step) {
    column.z() = z;
    const VoxelT* v = map.voxel(column, scale);
    const double centre_z = map.voxel_centre_W(column, scale).z();
    if (v != nullptr && voxel_observed(*v) && previous != nullptr && voxel_observed(*previous) &&
        voxel_tsdf(*previous) > 0.0f && voxel_tsdf(*v) <= 0.0f) {
      const double a = voxel_tsdf(*previous);
      const double b = voxel_tsdf(*v);
      return previous_z + (centre_z - previous_z) * a / (a - b);
    }
    previous = v;
    previous_z = centre_z;
  }
  return std::nan("");
}

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
    const TestType* a = full.map.voxel(column, 0);
    const TestType* b = cut.map.voxel(column, 0);
    if (a == nullptr || b == nullptr) continue;
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
      const MultiresVoxel* v = fusion.map.voxel(column, scale);
      if (v == nullptr) continue;  // not in the band's blocks
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
      const MultiresVoxel* va = a.scale_begin(scale);
      const Multires16Voxel* vb = b.scale_begin(scale);
      for (int k = 0; k < block_scale_count(scale); ++k) {
        // Whole sample counts: the weights are exact.
        REQUIRE(voxel_weight(vb[k]) == voxel_weight(va[k]));
        REQUIRE(voxel_delta_y(vb[k]) == voxel_delta_y(va[k]));
        if (!voxel_observed(va[k])) continue;
        worst = std::max(worst, std::abs(double{voxel_tsdf(vb[k])} - voxel_tsdf(va[k])));
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

// Every voxel at scale s+1 equals the eq. 4 mean of its observed children, bit for bit.
template <typename Block>
void require_consistent_mips(const Block& block, int from_scale, int to_scale) {
  for (int s = from_scale; s < to_scale; ++s) {
    const int n = block_scale_side(s + 1);
    for (int z = 0; z < n; ++z)
      for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
          float sum = 0.0f;
          float weight = 0.0f;
          int observed = 0;
          for (int c = 0; c < 8; ++c) {
            const MultiresVoxel& child =
                block.at(2 * x + (c & 1), 2 * y + ((c >> 1) & 1), 2 * z + ((c >> 2) & 1), s);
            if (!voxel_observed(child)) continue;
            sum += child.x;
            weight += child.y;
            ++observed;
          }
          if (observed == 0) continue;
          const MultiresVoxel& parent = block.at(x, y, z, s + 1);
          REQUIRE(parent.x == sum / static_cast<float>(observed));
          REQUIRE(parent.y == std::ceil(weight / static_cast<float>(observed)));
          REQUIRE(parent.x_last == parent.x);
          REQUIRE(parent.delta_y == 0.0f);
        }
  }
}

// A near sphere (scale 0 from this camera) and a far one (scale 1), side by side.
AnalyticScene near_and_far_spheres() {
  AnalyticScene scene;
  scene.spheres.push_back({Eigen::Vector3d(-0.3, 0.0, 1.0), 0.25});
  scene.spheres.push_back({Eigen::Vector3d(0.4, 0.0, 2.05), 0.2});
  return scene;
}

TEST_CASE(
    "after integration parents are exactly the mean of observed children, up to the "
    "coarsest scale of the frame and on to the root",
    "[fusion][integrator]") {
  const AnalyticScene scene = near_and_far_spheres();
  Fusion<MultiresVoxel> fusion(map_config(0.01f, 8, 8000), fusion_config(0.08f),
                               test::centred_camera(160, 120, 131.0f));
  const IntegrationReport r = fusion.fuse(scene, test::looking_along_z({0, 0, -0.25}));
  REQUIRE(r.status.ok());
  REQUIRE(r.blocks_per_scale[0] > 0);
  REQUIRE(r.blocks_per_scale[1] > 0);
  REQUIRE(fusion.fuse(scene, test::looking_along_z({0.02, 0, -0.25})).status.ok());
  std::uint32_t lifted = 0;
  for (std::uint32_t i = 0; i < fusion.map.block_count(); ++i) {
    const VoxelBlock<MultiresVoxel>& b = fusion.map.block(i);
    if (!b.integrated()) continue;
    // Up-propagation stops at the coarsest scale integrated in the frame (here 1).
    REQUIRE(b.mip_scale == std::max<int>(b.current_scale, 1));
    require_consistent_mips(b, b.current_scale, b.mip_scale);
    if (b.current_scale == 0) ++lifted;
  }
  CHECK(lifted > 10);
  // The root sees the surface (a reference stopped at the block's parent).
  const NodeSummary& root = fusion.map.node(Octree<MultiresVoxel>::root_index()).summary;
  CHECK(root.observed());
  CHECK(root.tsdf_min < 0.0f);
  CHECK(root.tsdf_max > 0.0f);
  const OctreeNode& parent = fusion.map.node(fusion.map.block(0).parent_node);
  CHECK(parent.summary.observed());
}

TEST_CASE("delta_y counts applied updates only", "[fusion][integrator]") {
  // A plane at z = 1.03: voxels more than mu behind it (in the block the band ends in) are
  // never updated.
  constexpr double kPlaneZ_m = 1.03;
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), kPlaneZ_m});
  constexpr int kFrames = 3;
  Fusion<MultiresVoxel> fusion(map_config(0.01f, 8, 8000), fusion_config(0.08f, 0),
                               test::centred_camera(160, 120, 131.0f));
  for (int i = 0; i < kFrames; ++i) {
    REQUIRE(fusion.fuse(scene, test::looking_along_z({0, 0, 0.3})).status.ok());
  }
  const Octree<MultiresVoxel>& map = fusion.map;
  const Eigen::Vector3i column(128, 128, 0);
  int applied = 0;
  int rejected = 0;
  for (int z = 0; z < 256; ++z) {
    const Eigen::Vector3i v(column.x(), column.y(), z);
    const MultiresVoxel* voxel = map.voxel(v, 0);
    if (voxel == nullptr) continue;
    const double d = kPlaneZ_m - map.voxel_centre_W(v).z();
    if (d < -0.08 - 0.005) {
      CHECK(voxel->delta_y == 0.0f);
      CHECK(voxel->y == 0.0f);
      ++rejected;
    } else if (d > -0.08 + 0.005) {
      CHECK(voxel->delta_y == static_cast<float>(kFrames));
      CHECK(voxel->y == static_cast<float>(kFrames));
      ++applied;
    }
  }
  CHECK(applied > 5);
  CHECK(rejected > 0);
}

TEST_CASE("refinement down-propagates, then up-propagates in the same frame",
          "[fusion][integrator]") {
  const AnalyticScene scene = near_and_far_spheres();
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  const Se3d pose = test::looking_along_z({0, 0, -0.25});
  // First frame with every block at scale 1, then automatic scales: the near sphere's blocks
  // refine to 0 while the far sphere's stay at 1.
  Fusion<MultiresVoxel> fusion(map_config(0.01f, 8, 8000), fusion_config(0.08f, 1), camera);
  REQUIRE(fusion.fuse(scene, pose).status.ok());
  Integrator<MultiresVoxel> automatic;
  const FusionConfig fc = fusion_config(0.08f);
  test::ArenaBuffer extra(Integrator<MultiresVoxel>::bytes_required(fc, 160, 120));
  REQUIRE(automatic.reserve(extra.arena(), fc, 160, 120).ok());
  const IntegrationReport r =
      automatic.integrate(fusion.map, ImageView<const float>(fusion.depth.data(), 160, 120), camera,
                          pose, 1, FusionBudget(), WorkerTeam(1));
  REQUIRE(r.status.ok());
  CHECK(r.blocks_refined == r.blocks_per_scale[0]);
  CHECK(r.blocks_refined > 10);
  CHECK(r.blocks_per_scale[1] > 0);
  for (std::uint32_t i = 0; i < fusion.map.block_count(); ++i) {
    const VoxelBlock<MultiresVoxel>& b = fusion.map.block(i);
    if (!b.integrated() || b.current_scale != 0) continue;
    CHECK(b.min_scale == 0);
    REQUIRE(b.mip_scale == 1);
    require_consistent_mips(b, 0, 1);  // scale 1 is fresh after the refining frame
  }
  // Interpolated-then-updated voxels: the near sphere still crosses within a quarter voxel.
  const Eigen::Vector3i column = fusion.map.point_to_voxel(Eigen::Vector3f(-0.3f, 0.0f, 0.0f));
  const Eigen::Vector3f c = fusion.map.voxel_centre_W(column, 0);
  const double dx = c.x() + 0.3;
  const double dy = c.y();
  const double truth = 1.0 - std::sqrt(0.25 * 0.25 - dx * dx - dy * dy);
  const double z = zero_crossing_z(fusion.map, column, 0, 0, 256);
  CAPTURE(truth, z);
  CHECK(std::abs(z - truth) <= 0.25 * 0.01);
}

TEST_CASE("the thin-structure promise: close, far at scale 3, close again keeps the detail",
          "[fusion][integrator][thin]") {
  // A thin pole (radius 1.5 cm, 3 finest voxels) in front of a wall. Footprint ratio
  // r = z / (fx * voxel) = z / 0.655 m: scale 0 below 0.98 m, scale 3 beyond 3.93 m.
  constexpr float kVoxel_m = 0.005f;
  constexpr double kPoleRadius_m = 0.015;
  const Eigen::Vector3d pole(0.0025, 0.0, 1.5025);
  AnalyticScene scene;
  scene.cylinders.push_back({pole, kPoleRadius_m, -1.0, 1.0});
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), 2.0});
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  MapConfig mc = MapConfig::centred(Eigen::Vector3f(0.0f, 0.0f, 0.0f), kVoxel_m, 11, 60000, 60000);
  FusionConfig fc = fusion_config(8 * kVoxel_m);
  fc.max_blocks_per_frame = 1u << 16;
  Fusion<MultiresVoxel> fusion(mc, fc, camera);
  const Se3d close = test::looking_along_z({0, 0, 0.75});
  const Se3d far = test::looking_along_z({0, 0, -3.0});
  auto front_surface = [&]() {
    // Along z through the pole's axis (the pole's front at z = 1.4875).
    const Eigen::Vector3i column =
        fusion.map.point_to_voxel(Eigen::Vector3f(static_cast<float>(pole.x()), 0.0f, 0.0f));
    const int z0 = fusion.map.point_to_voxel(Eigen::Vector3f(0, 0, 1.3f)).z();
    const int z1 = fusion.map.point_to_voxel(Eigen::Vector3f(0, 0, 1.6f)).z();
    return zero_crossing_z(fusion.map, column, 0, z0, z1);
  };
  const double truth = pole.z() - kPoleRadius_m;
  constexpr double kTolerance_m = 0.25 * kVoxel_m;
  const Eigen::Vector3i pole_voxel = fusion.map.point_to_voxel(
      Eigen::Vector3f(static_cast<float>(pole.x()), 0.0f, static_cast<float>(truth)));
  for (int i = 0; i < 20; ++i) REQUIRE(fusion.fuse(scene, close).status.ok());
  REQUIRE(fusion.map.find_block_at_voxel(pole_voxel)->current_scale == 0);
  const double before = front_surface();
  REQUIRE(std::abs(before - truth) <= kTolerance_m);

  for (int i = 0; i < 5; ++i) REQUIRE(fusion.fuse(scene, far).status.ok());
  REQUIRE(fusion.map.find_block_at_voxel(pole_voxel)->current_scale == 3);
  // At scale 3 (4 cm voxels) a 3 cm pole is below the resolution of the current scale.

  for (int i = 0; i < 6; ++i) REQUIRE(fusion.fuse(scene, close).status.ok());
  const VoxelBlock<MultiresVoxel>* block = fusion.map.find_block_at_voxel(pole_voxel);
  CHECK(block->current_scale == 0);
  CHECK(block->min_scale == 0);
  const double after = front_surface();
  CAPTURE(truth, before, after);
  REQUIRE(std::isfinite(after));
  // The coarse frames' change reaches the fine voxels as one delta (eq. 5), which shifts the
  // crossing a little; the detail itself (a 3 cm pole in 4 cm coarse voxels) survives.
  constexpr double kAfterTolerance_m = kVoxel_m;
  CHECK(std::abs(after - truth) <= kAfterTolerance_m);
}

TEST_CASE("blocks never integrated at scale 0 hold no finest level",
          "[fusion][integrator][finest]") {
  const AnalyticScene scene = near_and_far_spheres();
  Fusion<MultiresVoxel> fusion(map_config(0.01f, 8, 8000), fusion_config(0.08f),
                               test::centred_camera(160, 120, 131.0f));
  for (int i = 0; i < 3; ++i) {
    const IntegrationReport r = fusion.fuse(scene, test::looking_along_z({0.01 * i, 0, -0.25}));
    REQUIRE(r.status.ok());
    CHECK(r.finest_refusals == 0);
  }
  std::uint32_t with_finest = 0;
  std::uint32_t coarse_only = 0;
  for (std::uint32_t i = 0; i < fusion.map.block_count(); ++i) {
    const VoxelBlock<MultiresVoxel>& b = fusion.map.block(i);
    CAPTURE(i, static_cast<int>(b.min_scale));
    REQUIRE(b.has_finest() == (b.min_scale == 0));
    with_finest += b.has_finest() ? 1u : 0u;
    coarse_only += b.integrated() && b.min_scale > 0 ? 1u : 0u;
  }
  CHECK(with_finest > 10);  // the near sphere
  CHECK(coarse_only > 10);  // the far sphere
  const MapMemory m = fusion.map.memory();
  CHECK(m.finest_used == with_finest);
  CHECK(m.bytes_used == m.blocks_used * sizeof(VoxelBlock<MultiresVoxel>) +
                            with_finest * sizeof(FinestLevel<MultiresVoxel>) +
                            m.nodes_used * sizeof(OctreeNode));
}

TEST_CASE("refining from scale 3 to 0 takes a finest level and down-propagates into it",
          "[fusion][integrator][finest]") {
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0.2, 0.1, 1).normalized(), 1.1});
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  const Se3d pose = test::looking_along_z({0, 0, 0.2});
  Fusion<MultiresVoxel> fusion(map_config(0.01f, 8, 8000), fusion_config(0.08f, 3), camera);
  REQUIRE(fusion.fuse(scene, pose).status.ok());
  // The single scale-3 voxel of each block after the coarse frame.
  const std::uint32_t coarse_blocks = fusion.map.block_count();
  std::vector<MultiresVoxel> coarse(coarse_blocks);
  for (std::uint32_t i = 0; i < coarse_blocks; ++i) {
    const VoxelBlock<MultiresVoxel>& b = fusion.map.block(i);
    REQUIRE(b.current_scale == 3);
    REQUIRE_FALSE(b.has_finest());
    coarse[i] = b.at(0, 0, 0, 3);
  }
  CHECK(fusion.map.memory().finest_used == 0);

  Integrator<MultiresVoxel> fine;
  const FusionConfig fc = fusion_config(0.08f, 0);
  test::ArenaBuffer extra(Integrator<MultiresVoxel>::bytes_required(fc, 160, 120));
  REQUIRE(fine.reserve(extra.arena(), fc, 160, 120).ok());
  const IntegrationReport r =
      fine.integrate(fusion.map, ImageView<const float>(fusion.depth.data(), 160, 120), camera,
                     pose, 1, FusionBudget(), WorkerTeam(1));
  REQUIRE(r.status.ok());
  CHECK(r.blocks_refined == coarse_blocks);
  CHECK(r.blocks_per_scale[0] == r.blocks_integrated);
  CHECK(fusion.map.memory().finest_used == r.blocks_integrated);
  // A single coarse voxel interpolates to a constant: every finest voxel starts at the coarse
  // value and weight (eq. 5), then this frame's update adds one sample to some of them.
  constexpr float kInterpolationTolerance = 1e-6f;
  std::uint64_t updated = 0;
  for (std::uint32_t i = 0; i < fusion.map.block_count(); ++i) {
    const VoxelBlock<MultiresVoxel>& b = fusion.map.block(i);
    REQUIRE(b.has_finest());
    REQUIRE(b.current_scale == 0);
    const MultiresVoxel parent = i < coarse_blocks ? coarse[i] : MultiresVoxel();
    for (int v = 0; v < kBlockFinestVoxelCount; ++v) {
      const MultiresVoxel& child = b.scale_begin(0)[v];
      CAPTURE(i, v, parent.x, parent.y, child.x, child.y);
      if (child.y == parent.y + 1.0f) {
        ++updated;
        continue;
      }
      REQUIRE(child.y == parent.y);
      if (voxel_observed(parent)) {
        REQUIRE(std::abs(child.x - parent.x) <= kInterpolationTolerance);
        REQUIRE(child.delta_y == 0.0f);
      }
    }
  }
  CHECK(updated == r.voxels_updated);
}

TEST_CASE("a full finest-level pool keeps blocks at scale 1, counted, and the map valid",
          "[fusion][integrator][finest]") {
  constexpr double kPlaneZ_m = 1.237;
  constexpr float kVoxel_m = 0.01f;
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), kPlaneZ_m});
  MapConfig mc = map_config(kVoxel_m, 8, 8000);
  constexpr std::uint32_t kFinest = 12;
  mc.finest_capacity = kFinest;
  Fusion<MultiresVoxel> fusion(mc, fusion_config(8 * kVoxel_m, 0),
                               test::centred_camera(160, 120, 131.0f));
  for (int frame = 0; frame < 2; ++frame) {
    const IntegrationReport r = fusion.fuse(scene, test::looking_along_z({0, 0, 0.1}));
    CAPTURE(frame);
    CHECK(r.status == StatusCode::resource_exhausted);
    REQUIRE(r.blocks_integrated > kFinest);
    CHECK(r.blocks_per_scale[0] == kFinest);
    CHECK(r.blocks_per_scale[1] == r.blocks_integrated - kFinest);
    CHECK(r.finest_refusals == r.blocks_integrated - kFinest);  // again every frame
    CHECK(r.pool_refusals == r.finest_refusals);
    CHECK(r.blocks_allocated == (frame == 0 ? r.blocks_integrated : 0u));
  }
  const MapMemory m = fusion.map.memory();
  CHECK(m.finest_used == kFinest);
  CHECK(m.finest_refusals > 0);
  CHECK(m.refusals == m.finest_refusals);
  for (std::uint32_t i = 0; i < fusion.map.block_count(); ++i) {
    const VoxelBlock<MultiresVoxel>& b = fusion.map.block(i);
    REQUIRE(b.current_scale == (b.has_finest() ? 0 : 1));
    REQUIRE(b.min_scale == b.current_scale);
  }
  // Every block holds scale 1 (the refused ones fused there, the others up-propagated to it):
  // the plane reads back at scale 1 within a quarter of its voxel.
  constexpr double kTolerance_m = 0.25 * 2 * kVoxel_m;
  for (const Eigen::Vector3i& column :
       {Eigen::Vector3i(128, 128, 0), Eigen::Vector3i(100, 150, 0), Eigen::Vector3i(150, 110, 0)}) {
    CAPTURE(column.transpose());
    const double z = zero_crossing_z(fusion.map, column, 1, 0, 256);
    REQUIRE(std::isfinite(z));
    CHECK(std::abs(z - kPlaneZ_m) <= kTolerance_m);
  }
}

// Both maps hold the same blocks, voxels and node summaries, bit for bit.
template <typename VoxelT>
void require_same_map(const Octree<VoxelT>& one, const Octree<VoxelT>& two) {
  REQUIRE(one.block_count() == two.block_count());
  using Block = VoxelBlock<VoxelT>;
  for (std::uint32_t i = 0; i < one.block_count(); ++i) {
    const Block& a = one.block(i);
    const Block& b = two.block(i);
    // Everything but the finest-level pointer (into two different pools) byte for byte.
    const std::size_t header = static_cast<std::size_t>(reinterpret_cast<const char*>(&a.finest) -
                                                        reinterpret_cast<const char*>(&a));
    REQUIRE(std::memcmp(&a, &b, header) == 0);
    REQUIRE(std::memcmp(a.inline_voxels, b.inline_voxels, sizeof(a.inline_voxels)) == 0);
    REQUIRE(a.has_finest() == b.has_finest());
    REQUIRE(std::memcmp(a.scale_begin(0), b.scale_begin(0),
                        sizeof(VoxelT) * kBlockFinestVoxelCount) == 0);
  }
  REQUIRE(one.memory().finest_used == two.memory().finest_used);
  for (std::uint32_t i = 0; i < one.node_count(); ++i) {
    const NodeSummary& a = one.node(i).summary;
    const NodeSummary& b = two.node(i).summary;
    REQUIRE(std::memcmp(&a, &b, sizeof(NodeSummary)) == 0);
  }
}

TEMPLATE_TEST_CASE("results are bit-identical for 1, 2 and 3 workers",
                   "[fusion][integrator][threads]", MultiresVoxel, Multires16Voxel) {
  AnalyticScene scene;
  scene.spheres.push_back({Eigen::Vector3d(0.1, 0.0, 1.3), 0.3});
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), 1.9});
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  const int workers = GENERATE(2, 3);
  CAPTURE(workers);
  Fusion<TestType> one(map_config(0.01f, 8, 8000), fusion_config(0.08f), camera);
  Fusion<TestType> two(map_config(0.01f, 8, 8000), fusion_config(0.08f), camera);
  for (int i = 0; i < 6; ++i) {
    // Moving back then forward: blocks change scale both ways.
    const Se3d pose = test::looking_along_z({0.02 * i, 0.0, -0.6 + 0.25 * (i % 4)});
    const IntegrationReport a = one.fuse(scene, pose, FusionBudget(), 1);
    const IntegrationReport b = two.fuse(scene, pose, FusionBudget(), workers);
    REQUIRE(a.status.ok());
    REQUIRE(b.status.ok());
    REQUIRE(a.voxels_updated == b.voxels_updated);
    REQUIRE(a.blocks_integrated == b.blocks_integrated);
  }
  require_same_map(one.map, two.map);
}

TEST_CASE("a band of rows whose cell list fills up is finished by the merge, same map",
          "[fusion][integrator][threads]") {
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  // Depth only in the first rows: every block comes from the first band, whose list holds a
  // quarter of max_blocks_per_frame.
  auto fill = [&camera](std::vector<float>& depth) {
    depth.assign(static_cast<std::size_t>(camera.width) * camera.height, 0.0f);
    for (int v = 0; v < 15; ++v) {
      for (int u = 0; u < camera.width; ++u) depth[v * camera.width + u] = 1.0f + 0.001f * u;
    }
  };
  FusionConfig small = fusion_config(0.08f);
  small.max_blocks_per_frame = 256;
  Fusion<MultiresVoxel> tight(map_config(0.01f, 8, 8000), small, camera);
  Fusion<MultiresVoxel> tight_two(map_config(0.01f, 8, 8000), small, camera);
  Fusion<MultiresVoxel> roomy(map_config(0.01f, 8, 8000), fusion_config(0.08f), camera);
  WorkerTeam one_worker(1);
  WorkerTeam two_workers(2);
  for (int i = 0; i < 3; ++i) {
    const Se3d pose = test::looking_along_z({0.01 * i, 0.0, 0.1 * i});
    fill(tight.depth);
    fill(tight_two.depth);
    fill(roomy.depth);
    const IntegrationReport a = tight.fuse_rendered(pose, FusionBudget(), one_worker);
    const IntegrationReport b = tight_two.fuse_rendered(pose, FusionBudget(), two_workers);
    const IntegrationReport c = roomy.fuse_rendered(pose, FusionBudget(), one_worker);
    REQUIRE(a.status.ok());
    REQUIRE(a.keys_dropped == 0);
    REQUIRE(a.blocks_touched > 64);  // more than the band's list holds
    REQUIRE(a.blocks_touched == c.blocks_touched);
    REQUIRE(b.blocks_touched == c.blocks_touched);
    REQUIRE(a.voxels_updated == c.voxels_updated);
    REQUIRE(b.voxels_updated == c.voxels_updated);
  }
  require_same_map(tight.map, roomy.map);
  require_same_map(tight_two.map, roomy.map);
}

TEST_CASE("no heap allocation per frame", "[fusion][integrator][alloc]") {
  AnalyticScene scene;
  scene.spheres.push_back({Eigen::Vector3d(0.0, 0.0, 1.2), 0.2});
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), 1.8});
  const PinholeCamera camera = test::centred_camera(80, 60, 65.0f);
  // Coarse voxels keep this many-frame test quick in debug builds.
  Fusion<MultiresVoxel> multires(map_config(0.05f, 7, 2000), fusion_config(0.4f), camera);
  Fusion<TsdfVoxel> single(map_config(0.05f, 7, 2000), fusion_config(0.4f), camera);
  WorkerTeam team(2);
  constexpr int kFrames = 120;
  std::vector<std::vector<float>> images(8);
  for (int k = 0; k < 8; ++k) {
    scene.render(camera, test::looking_along_z({0.01 * k, 0.0, -0.8 + 0.2 * k}), images[k]);
  }
  test::AllocationScope scope;
  for (int i = 0; i < kFrames; ++i) {
    const int k = i % 8;
    const Se3d pose = test::looking_along_z({0.01 * k, 0.0, -0.8 + 0.2 * k});
    multires.depth.swap(images[k]);
    single.depth.swap(multires.depth);
    REQUIRE(single.fuse_rendered(pose, FusionBudget(), team).status.ok());
    multires.depth.swap(single.depth);
    REQUIRE(multires.fuse_rendered(pose, FusionBudget(), team).status.ok());
    images[k].swap(multires.depth);
  }
  CHECK(scope.allocations() == 0);
}

TEST_CASE("a full block pool is reported and the map stays usable", "[fusion][integrator]") {
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), 1.0});
  constexpr std::uint32_t kBlocks = 40;
  Fusion<MultiresVoxel> fusion(map_config(0.01f, 8, kBlocks), fusion_config(0.08f),
                               test::centred_camera(160, 120, 131.0f));
  const IntegrationReport first = fusion.fuse(scene, test::looking_along_z({0, 0, 0.3}));
  CHECK(first.status == StatusCode::resource_exhausted);
  CHECK(first.blocks_requested > kBlocks);
  CHECK(first.blocks_allocated == kBlocks);
  CHECK(first.pool_refusals == first.blocks_requested - kBlocks);
  CHECK(first.blocks_integrated == kBlocks);
  CHECK(fusion.map.block_count() == kBlocks);
  const IntegrationReport second = fusion.fuse(scene, test::looking_along_z({0, 0, 0.3}));
  CHECK(second.status == StatusCode::resource_exhausted);
  CHECK(second.blocks_allocated == 0);
  CHECK(second.blocks_integrated == kBlocks);
  for (std::uint32_t i = 0; i < kBlocks; ++i) {
    const VoxelBlock<MultiresVoxel>& b = fusion.map.block(i);
    CHECK(b.last_updated_frame == 1);
  }
}

TEST_CASE("budgets bind in the documented order", "[fusion][integrator][budget]") {
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0.3, 0, 1).normalized(), 1.0});
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  const Se3d pose = test::looking_along_z({0, 0, 0.3});

  SECTION("new blocks: the nearest are allocated") {
    Fusion<MultiresVoxel> fusion(map_config(0.01f, 8, 8000), fusion_config(0.08f), camera);
    FusionBudget budget;
    budget.max_new_blocks = 20;
    const IntegrationReport r = fusion.fuse(scene, pose, budget);
    CHECK(r.status.ok());
    CHECK(r.budget_hit);
    CHECK(r.blocks_allocated == 20);
    CHECK(r.budget_blocks_not_allocated == r.blocks_requested - 20);
    // Every allocated block is at least as near as every one left out.
    float farthest_kept = 0.0f;
    for (std::uint32_t i = 0; i < fusion.map.block_count(); ++i) {
      const Eigen::Vector3f c = fusion.map.block_centre_W(fusion.map.block(i).coords);
      farthest_kept = std::max(farthest_kept, c.z() - 0.3f);
    }
    const IntegrationReport all = fusion.fuse(scene, pose);
    CHECK(all.blocks_allocated == r.budget_blocks_not_allocated);
    for (std::uint32_t i = 20; i < fusion.map.block_count(); ++i) {
      const Eigen::Vector3f c = fusion.map.block_centre_W(fusion.map.block(i).coords);
      CHECK(c.z() - 0.3f >= farthest_kept);
    }
  }
  SECTION("voxel updates: the farthest blocks go one scale coarser, then are skipped") {
    Fusion<MultiresVoxel> fusion(map_config(0.01f, 8, 8000), fusion_config(0.08f, 0), camera);
    const IntegrationReport free_run = fusion.fuse(scene, pose);
    const std::uint32_t n = free_run.blocks_integrated;
    FusionBudget budget;
    budget.max_voxel_updates = 512ull * n - 400;  // forces a few blocks to scale 1
    const IntegrationReport r = fusion.fuse(scene, pose, budget);
    CHECK(r.budget_hit);
    CHECK(r.budget_blocks_coarsened == 1);
    CHECK(r.blocks_per_scale[1] == 1);
    CHECK(r.budget_blocks_skipped == 0);
    budget.max_voxel_updates = 64ull * n / 2;  // even all at scale 1 is too much
    const IntegrationReport tight = fusion.fuse(scene, pose, budget);
    CHECK(tight.budget_blocks_coarsened == n);
    CHECK(tight.budget_blocks_skipped > 0);
    CHECK(tight.blocks_integrated + tight.budget_blocks_skipped == n);
    CHECK(64ull * tight.blocks_integrated <= budget.max_voxel_updates);
  }
  SECTION("integrated blocks: the farthest are skipped") {
    Fusion<TsdfVoxel> fusion(map_config(0.01f, 8, 8000), fusion_config(0.08f), camera);
    const IntegrationReport free_run = fusion.fuse(scene, pose);
    FusionBudget budget;
    budget.max_integrated_blocks = 10;
    const IntegrationReport r = fusion.fuse(scene, pose, budget);
    CHECK(r.budget_hit);
    CHECK(r.blocks_integrated == 10);
    CHECK(r.budget_blocks_skipped == free_run.blocks_integrated - 10);
  }
}

TEST_CASE("bad input is refused without touching the map", "[fusion][integrator]") {
  AnalyticScene scene;
  scene.planes.push_back({Eigen::Vector3d(0, 0, 1), 1.0});
  const PinholeCamera camera = test::centred_camera(160, 120, 131.0f);
  Fusion<MultiresVoxel> fusion(map_config(0.01f, 8, 8000), fusion_config(0.08f), camera);
  scene.render(camera, Se3d::Identity(), fusion.depth);
  const ImageView<const float> view(fusion.depth.data(), 160, 120);
  WorkerTeam team(1);
  Se3d bad_pose = Se3d::Identity();
  bad_pose.matrix()(0, 3) = std::numeric_limits<double>::quiet_NaN();
  CHECK(fusion.integrator.integrate(fusion.map, view, camera, bad_pose, 0, FusionBudget(), team)
            .status == StatusCode::invalid_argument);
  Se3d skew = Se3d::Identity();
  skew.matrix()(0, 0) = 2.0;
  CHECK(
      fusion.integrator.integrate(fusion.map, view, camera, skew, 0, FusionBudget(), team).status ==
      StatusCode::invalid_argument);
  PinholeCamera wrong = camera;
  wrong.width = 80;
  CHECK(fusion.integrator
            .integrate(fusion.map, view, wrong, Se3d::Identity(), 0, FusionBudget(), team)
            .status == StatusCode::invalid_argument);
  const ImageView<const float> small(fusion.depth.data(), 80, 60);
  PinholeCamera small_camera = test::centred_camera(80, 60, 65.0f);
  CHECK(fusion.integrator
            .integrate(fusion.map, small, small_camera, Se3d::Identity(), 0, FusionBudget(), team)
            .status == StatusCode::failed_precondition);
  CHECK(fusion.map.block_count() == 0);
  // A rigid pose far outside the cube: every ray misses it.
  Se3d far_away = Se3d::Identity();
  far_away.translation() = Eigen::Vector3d(1e30, -1e30, 1e25);
  const IntegrationReport outside =
      fusion.integrator.integrate(fusion.map, view, camera, far_away, 0, FusionBudget(), team);
  CHECK(outside.status.ok());
  CHECK(outside.rays_outside_cube > 0);
  CHECK(fusion.map.block_count() == 0);
  // NaN and negative depths are no measurement.
  for (std::size_t i = 0; i < fusion.depth.size(); ++i) {
    fusion.depth[i] = (i % 2 == 0) ? std::numeric_limits<float>::quiet_NaN() : -1.0f;
  }
  const IntegrationReport r = fusion.integrator.integrate(
      fusion.map, view, camera, Se3d::Identity(), 0, FusionBudget(), team);
  CHECK(r.status.ok());
  CHECK(r.blocks_touched == 0);
  CHECK(fusion.map.block_count() == 0);
}

}  // namespace
}  // namespace octofuse
