// The distance field against analytic scenes written straight into the map: a sphere over a
// floor, whose exact distance is known everywhere.
#include "octofuse/query/esdf.hpp"

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <catch2/catch.hpp>

#include "support/aligned_buffer.hpp"
#include "support/analytic_map.hpp"

namespace octofuse {
namespace {

constexpr float kVoxel_m = 0.02f;
constexpr float kMu_m = 0.08f;

struct Scene {
  Eigen::Vector3f centre = Eigen::Vector3f(0.1f, -0.05f, 0.2f);
  float radius = 0.3f;
  float floor_z = -0.8f;
  bool with_sphere = true;
  bool with_box = false;  // a second object added later
  float operator()(const Eigen::Vector3f& p) const {
    float d = p.z() - floor_z;
    if (with_sphere) d = std::min(d, (p - centre).norm() - radius);
    if (with_box) {
      const Eigen::Vector3f q =
          (p - Eigen::Vector3f(-0.6f, 0.5f, -0.4f)).cwiseAbs() - Eigen::Vector3f(0.15f, 0.1f, 0.2f);
      const float outside = q.cwiseMax(0.0f).norm();
      const float inside = std::min(q.maxCoeff(), 0.0f);
      d = std::min(d, outside + inside);
    }
    return d;
  }
};

MapConfig map_config() {
  return MapConfig::centred(Eigen::Vector3f::Zero(), kVoxel_m, 7, 40000, 40000);
}

EsdfConfig field_config() {
  EsdfConfig c;
  c.enabled = true;
  c.cells_per_side = 64;
  c.cell_voxels = 2;
  c.max_cell_steps = 0;
  return c;
}

struct Field {
  explicit Field(const EsdfConfig& config) : memory(EsdfField::bytes_required(config)) {
    REQUIRE(field.reserve(memory.arena(), config, map_config()).ok());
    REQUIRE(memory.arena().bytes_used() <= memory.bytes());
  }
  test::ArenaBuffer memory;
  EsdfField field;
};

// Over `samples` points drawn by `draw`, those outside the exact surface (`exact` > 0): how many,
// how many the field reports farther than the exact distance plus a finest voxel (unsafe), and
// the largest excess.
struct UnsafeTally {
  long points = 0;
  long unsafe = 0;
  float worst = -1.0f;
};
template <typename Exact, typename Draw>
UnsafeTally tally_unsafe(const EsdfField& field, const Exact& exact, Draw&& draw, int samples) {
  UnsafeTally t;
  for (int i = 0; i < samples; ++i) {
    const Eigen::Vector3f p = draw();
    const float exact_m = exact(p);
    if (exact_m <= 0.0f) continue;
    const EsdfAnswer a = field.distance(p).value();
    REQUIRE(a.has_distance);
    ++t.points;
    t.worst = std::max(t.worst, a.distance_m - exact_m);
    if (a.distance_m > exact_m + kVoxel_m) ++t.unsafe;
  }
  return t;
}

struct Errors {
  long points = 0;
  long unsafe = 0;      // reported distance above the exact one by more than a finest voxel
  long over_bound = 0;  // lower bound above the exact distance
  long answered = 0;
  long close = 0;         // within 1 m of a surface
  double close_sq = 0.0;  // squared error there
  long far_gradient = 0;
  long bad_gradient = 0;
};

template <typename Sdf>
Errors measure(const EsdfField& field, const Sdf& sdf, int count) {
  Errors e;
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-1.27f, 1.27f);
  for (int i = 0; i < count; ++i) {
    const Eigen::Vector3f p(u(rng), u(rng), u(rng));
    const float exact = sdf(p);
    if (exact <= 0.0f) continue;  // inside: the field answers distances to surfaces outside
    ++e.points;
    const Result<EsdfAnswer> r = field.distance(p);
    REQUIRE(r.ok());
    const EsdfAnswer& a = r.value();
    if (!a.has_distance) continue;
    ++e.answered;
    if (a.distance_m > exact + kVoxel_m) ++e.unsafe;
    if (a.lower_bound_m > exact) ++e.over_bound;
    if (exact < 1.0f) {
      ++e.close;
      e.close_sq += (a.distance_m - exact) * (a.distance_m - exact);
    }
    if (exact > 0.2f) {
      // Exact gradient by central differences.
      Eigen::Vector3f g;
      for (int k = 0; k < 3; ++k) {
        Eigen::Vector3f h = Eigen::Vector3f::Zero();
        h[k] = 1e-3f;
        g[k] = (sdf(p + h) - sdf(p - h)) / 2e-3f;
      }
      if (g.norm() > 0.9f) {
        ++e.far_gradient;
        if (a.gradient.dot(g.normalized()) < 0.95f) ++e.bad_gradient;
      }
    }
  }
  return e;
}

TEST_CASE("the field's distances against a sphere over a floor: safe, accurate, with gradients") {
  test::OwnedMap<TsdfVoxel> owned(map_config());
  const Scene scene;
  test::fill_band(owned.map, kMu_m, scene, [](const Eigen::Vector3i&) { return 0; });
  Field f(field_config());
  const EsdfReport report = f.field.flush(owned.map, nullptr, kMu_m, 1, 1);
  REQUIRE(report.published);
  CHECK(f.field.published_version() == 1);

  const Errors e = measure(f.field, scene, 40000);
  REQUIRE(e.points > 20000);
  CHECK(e.answered == e.points);  // the window covers the cube and every point sees a surface
  CHECK(e.unsafe == 0);
  CHECK(e.over_bound == 0);
  const double rmse = std::sqrt(e.close_sq / static_cast<double>(e.close));
  INFO("rmse " << rmse << " m over " << e.close << " points");
  CHECK(rmse <= 0.5 * kVoxel_m);
  REQUIRE(e.far_gradient > 1000);
  // Off only next to the medial surface, where the nearest surface switches.
  CHECK(e.bad_gradient * 200 <= e.far_gradient);

  // Points next to the surfaces, by hand: above the sphere's top, above the floor.
  const EsdfAnswer top = f.field.distance(scene.centre + Eigen::Vector3f(0, 0, 0.5f)).value();
  CHECK(top.distance_m == Approx(0.2f).margin(kVoxel_m));
  CHECK(top.gradient.z() > 0.99f);
  const EsdfAnswer floor = f.field.distance(Eigen::Vector3f(-1.0f, -1.0f, -0.5f)).value();
  CHECK(floor.distance_m == Approx(0.3f).margin(kVoxel_m));
  CHECK(floor.gradient.z() > 0.99f);
  CHECK(floor.lower_bound_m <= 0.3f);
  CHECK(floor.lower_bound_m >= 0.3f - f.field.error_bound_m() - kVoxel_m);
}

// A box over the floor, its corners off the cells' grid; `rounding` rounds its edges and
// corners (m), as fusion does: a fused TSDF cuts a corner by most of a voxel.
struct BoxScene {
  Eigen::Vector3f centre = Eigen::Vector3f(0.13f, -0.07f, -0.31f);
  Eigen::Vector3f half = Eigen::Vector3f(0.237f, 0.151f, 0.183f);
  float floor_z = -0.8f;
  float rounding = 0.0f;
  float operator()(const Eigen::Vector3f& p) const {
    const Eigen::Vector3f q = (p - centre).cwiseAbs() - half + Eigen::Vector3f::Constant(rounding);
    const float box = q.cwiseMax(0.0f).norm() + std::min(q.maxCoeff(), 0.0f) - rounding;
    return std::min(p.z() - floor_z, box);
  }
};

TEST_CASE("next to a box's corners and edges the field stays within a voxel above the exact") {
  // Sites sit about a cell apart on the faces, none on the corner itself: a point out along a
  // corner's diagonal is nearer the corner than any site by up to half a cell. Each site stands
  // for the disc of surface around it, so the distance is to the nearest disc.
  test::OwnedMap<TsdfVoxel> owned(map_config());
  const BoxScene scene;
  BoxScene fused = scene;
  fused.rounding = kVoxel_m;
  test::fill_band(owned.map, kMu_m, fused, [](const Eigen::Vector3i&) { return 0; });
  Field f(field_config());
  REQUIRE(f.field.flush(owned.map, nullptr, kMu_m, 1, 1).published);
  long points = 0, unsafe = 0, band = 0;
  double band_sq = 0.0, worst = -1.0;
  for (int corner = 0; corner < 8; ++corner) {
    const Eigen::Vector3f sign((corner & 1) ? 1.0f : -1.0f, (corner & 2) ? 1.0f : -1.0f,
                               (corner & 4) ? 1.0f : -1.0f);
    const Eigen::Vector3f c = scene.centre + scene.half.cwiseProduct(sign);
    // Out from the corner, the edges and the faces next to it, 1 to 40 cm.
    for (int k = 1; k <= 400; ++k) {
      const float t = 0.001f * static_cast<float>(k);
      for (int dir = 1; dir < 8; ++dir) {
        const Eigen::Vector3f axes((dir & 1) ? sign.x() : 0.0f, (dir & 2) ? sign.y() : 0.0f,
                                   (dir & 4) ? sign.z() : 0.0f);
        const Eigen::Vector3f p =
            c + t * axes.normalized() + Eigen::Vector3f(0.003f, -0.002f, 0.001f);
        const float exact = scene(p);
        if (exact <= 0.0f) continue;
        const EsdfAnswer a = f.field.distance(p).value();
        REQUIRE(a.has_distance);
        ++points;
        worst = std::max(worst, static_cast<double>(a.distance_m - exact));
        if (a.distance_m > exact + kVoxel_m) ++unsafe;
        if (exact < kMu_m) {
          ++band;
          band_sq += (a.distance_m - exact) * (a.distance_m - exact);
        }
      }
    }
  }
  INFO("worst over " << worst << " m, band RMSE " << std::sqrt(band_sq / band) << " m over " << band
                     << " points");
  REQUIRE(points > 20000);
  CHECK(unsafe == 0);
  // Low by up to the disc radius where a disc reaches past an edge.
  CHECK(std::sqrt(band_sq / band) <= kVoxel_m);
  const Errors e = measure(f.field, scene, 40000);
  CHECK(e.unsafe == 0);
  CHECK(e.over_bound == 0);
  const double rmse = std::sqrt(e.close_sq / static_cast<double>(e.close));
  INFO("rmse " << rmse);
  CHECK(rmse <= 0.5 * kVoxel_m);
}

TEST_CASE("a bar thinner than a voxel is in the field though its TSDF never crosses zero") {
  // Across a bar of 1.2 cm at 2 cm voxels the sampled TSDF stays positive and nearly flat: no
  // zero crossing to project onto, no gradient to project along. The cell is an obstacle then.
  struct Bar {
    Eigen::Vector3f centre = Eigen::Vector3f(0.01f, 0.013f, 0.21f);
    Eigen::Vector3f half = Eigen::Vector3f(0.6f, 0.006f, 0.006f);
    float operator()(const Eigen::Vector3f& p) const {
      const Eigen::Vector3f q = (p - centre).cwiseAbs() - half;
      const float bar = q.cwiseMax(0.0f).norm() + std::min(q.maxCoeff(), 0.0f);
      return std::min(p.z() + 0.8f, bar);
    }
  };
  test::OwnedMap<TsdfVoxel> owned(map_config());
  const Bar bar;
  test::fill_band(owned.map, kMu_m, bar, [](const Eigen::Vector3i&) { return 0; });
  Field f(field_config());
  REQUIRE(f.field.flush(owned.map, nullptr, kMu_m, 1, 1).published);
  std::mt19937 rng(13);
  std::uniform_real_distribution<float> along(-0.5f, 0.5f);
  std::uniform_real_distribution<float> across(-0.3f, 0.3f);
  const UnsafeTally t = tally_unsafe(
      f.field, bar,
      [&] {
        return Eigen::Vector3f(bar.centre + Eigen::Vector3f(along(rng), across(rng), across(rng)));
      },
      20000);
  INFO("worst over " << t.worst << " m");
  REQUIRE(t.points > 19000);
  CHECK(t.unsafe == 0);
}

// A capsule of radius 7 mm along a slanted axis, off the cells' grid, over a floor.
struct ThinBar {
  Eigen::Vector3f point = Eigen::Vector3f(0.013f, 0.217f, 0.193f);
  Eigen::Vector3f axis = Eigen::Vector3f(1.0f, 0.3f, 0.1f).normalized();
  float radius = 0.007f;
  float axis_distance(const Eigen::Vector3f& p) const {
    const Eigen::Vector3f v = p - point;
    const float t = std::min(std::max(v.dot(axis), -0.6f), 0.6f);
    return (v - t * axis).norm();
  }
  float operator()(const Eigen::Vector3f& p) const {
    return std::min(p.z() + 0.8f, axis_distance(p) - radius);
  }
};

TEST_CASE("a thin part whose fused TSDF dips without crossing zero is in the field") {
  // Rays grazing past a part thinner than a couple of voxels write free space into its voxels:
  // the fused TSDF dips towards it, steeply, but its bottom stays well above zero (5-6 cm at
  // 2 cm voxels beside the sim room's chair stretchers, 3.5 cm at 1 cm beside the desk's
  // cable). Projecting a cell's centre along the gradient then lands beyond the part or short
  // of it, and cells a little further read too far for a site: no site on the part.
  constexpr float kWideMu_m = 0.16f;  // the sim's mu at 2 cm voxels
  const ThinBar bar;
  const auto fused = [&bar](const Eigen::Vector3f& p) {
    const float r = bar.axis_distance(p);
    const float dip = r < 0.02f ? 0.06f + 3.0f * r : 0.12f + (r - 0.02f);
    return std::min(p.z() + 0.8f, dip);
  };
  test::OwnedMap<TsdfVoxel> owned(map_config());
  test::fill_band(owned.map, kWideMu_m, fused, [](const Eigen::Vector3i&) { return 0; });
  Field f(field_config());
  REQUIRE(f.field.flush(owned.map, nullptr, kWideMu_m, 1, 1).published);
  std::mt19937 rng(17);
  std::uniform_real_distribution<float> along(-0.5f, 0.5f);
  std::uniform_real_distribution<float> across(-0.15f, 0.15f);
  const UnsafeTally t = tally_unsafe(
      f.field, bar,
      [&] {
        return Eigen::Vector3f(bar.point + along(rng) * bar.axis +
                               Eigen::Vector3f(0.0f, across(rng), across(rng)));
      },
      20000);
  INFO("worst over " << t.worst << " m");
  REQUIRE(t.points > 19000);
  CHECK(t.unsafe == 0);
  // Far from the bar the floor still reads right.
  const EsdfAnswer floor = f.field.distance(Eigen::Vector3f(-1.0f, -1.0f, -0.5f)).value();
  CHECK(floor.distance_m == Approx(0.3f).margin(kVoxel_m));
}

TEST_CASE("a point the map holds inside a part reads no distance to its surface") {
  // Where the map places a surface more than a voxel off (an underside or a floor seen at
  // grazing angles: fused 1-2 cm low at 2 cm voxels in the sim room), a point between the two
  // surfaces is free in truth but inside for the map. Its distance to the map's surface is
  // then no bound on its distance to the true one: it reads zero.
  constexpr float kFloor_m = -0.8f;
  constexpr float kFat_m = 0.03f;  // the map's floor lies 1.5 voxels above the true one
  const auto fused = [](const Eigen::Vector3f& p) { return 2.0f * (p.z() - kFloor_m - kFat_m); };
  test::OwnedMap<TsdfVoxel> owned(map_config());
  test::fill_band(owned.map, kMu_m, fused, [](const Eigen::Vector3i&) { return 0; });
  Field f(field_config());
  REQUIRE(f.field.flush(owned.map, nullptr, kMu_m, 1, 1).published);
  std::mt19937 rng(19);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::uniform_real_distribution<float> height(0.0f, 0.2f);
  long unsafe = 0, inside = 0;
  for (int i = 0; i < 20000; ++i) {
    const Eigen::Vector3f p(u(rng), u(rng), kFloor_m + height(rng));
    const float exact = p.z() - kFloor_m;
    const EsdfAnswer a = f.field.distance(p).value();
    REQUIRE(a.has_distance);
    if (a.distance_m > exact + kVoxel_m) ++unsafe;
    if (exact < 0.8f * kFat_m) {
      ++inside;
      CHECK(a.distance_m == 0.0f);
    } else if (exact > kFat_m + kVoxel_m) {
      // In front of the map's surface: the distance to it.
      CHECK(a.distance_m == Approx(exact - kFat_m).margin(0.25f * kVoxel_m));
    }
  }
  REQUIRE(inside > 1000);
  CHECK(unsafe == 0);
}

TEST_CASE("an update re-seeds only what changed and matches a rebuild from scratch") {
  test::OwnedMap<TsdfVoxel> owned(map_config());
  Scene scene;
  test::fill_band(owned.map, kMu_m, scene, [](const Eigen::Vector3i&) { return 0; });
  Field f(field_config());
  REQUIRE(f.field.flush(owned.map, nullptr, kMu_m, 0, 1).published);
  // Nothing changed: no work.
  CHECK(f.field.update(owned.map, nullptr, kMu_m, 1, 1).cell_steps == 0);

  // A box appears at frame 5: its blocks are newer than the published field.
  Scene with_box = scene;
  with_box.with_box = true;
  const int blocks_before = static_cast<int>(owned.map.block_count());
  const int blocks_per_side = owned.map.voxels_per_side() / kBlockSide;
  for (int z = 0; z < blocks_per_side; ++z) {
    for (int y = 0; y < blocks_per_side; ++y) {
      for (int x = 0; x < blocks_per_side; ++x) {
        const Eigen::Vector3i coords(x, y, z);
        const Eigen::Vector3f c = owned.map.block_centre_W(coords);
        const float reach = kMu_m + 0.5f * std::sqrt(3.0f) * map_config().block_size_m();
        if (std::fabs(with_box(c)) > reach || std::fabs(scene(c)) <= reach) continue;
        const Result<std::uint32_t> index = owned.map.allocate_block(coords);
        REQUIRE(index.ok());
        test::fill_block(owned.map, owned.map.block(index.value()), 0, kMu_m, with_box);
        owned.map.block(index.value()).last_updated_frame = 5;
      }
    }
  }
  REQUIRE(static_cast<int>(owned.map.block_count()) > blocks_before);
  const EsdfReport report = f.field.update(owned.map, nullptr, kMu_m, 5, 2);
  CHECK(report.published);
  CHECK(report.chunks_reseeded > 0);
  CHECK(report.chunks_reseeded < 64);  // of 512: only around the box

  // The same as a field built from nothing over the final map.
  Field fresh(field_config());
  REQUIRE(fresh.field.flush(owned.map, nullptr, kMu_m, 5, 2).published);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-1.27f, 1.27f);
  for (int i = 0; i < 5000; ++i) {
    const Eigen::Vector3f p(u(rng), u(rng), u(rng));
    const EsdfAnswer a = f.field.distance(p).value();
    const EsdfAnswer b = fresh.field.distance(p).value();
    REQUIRE(a.has_distance == b.has_distance);
    REQUIRE(a.distance_m == b.distance_m);
  }
  const Errors e = measure(f.field, with_box, 20000);
  CHECK(e.unsafe == 0);
  CHECK(e.over_bound == 0);
}

TEST_CASE("a map that changed only outside the window publishes the field it has, unswept") {
  test::OwnedMap<TsdfVoxel> owned(map_config());
  const Scene scene;
  test::fill_band(owned.map, kMu_m, scene, [](const Eigen::Vector3i&) { return 0; });
  EsdfConfig config = field_config();
  config.cells_per_side = 32;  // 64 voxels about the cube's middle: blocks 4-11 on each axis
  const std::uint32_t volume = 32u * 32u * 32u;
  Field f(config);
  REQUIRE(f.field.flush(owned.map, nullptr, kMu_m, 0, 1).published);
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> u(-0.3f, 0.3f);
  std::vector<Eigen::Vector3f> points;
  std::vector<EsdfAnswer> before;
  for (int i = 0; i < 2000; ++i) {
    points.emplace_back(u(rng), u(rng), u(rng));
    before.push_back(f.field.distance(points.back()).value());
  }

  // A block in the cube's corner, far outside the window, is fused at frame 7.
  const Eigen::Vector3i corner(0, 0, 0);
  if (owned.map.find_block(corner) == nullptr) REQUIRE(owned.map.allocate_block(corner).ok());
  owned.map.find_block(corner)->last_updated_frame = 7;
  const EsdfReport outside = f.field.update(owned.map, nullptr, kMu_m, 7, 2);
  CHECK(outside.published);
  CHECK(outside.chunks_reseeded == 0);
  CHECK(outside.cell_steps == volume);  // the seeding's pass, no sweeps
  CHECK(f.field.published_version() == 2);
  for (std::size_t i = 0; i < points.size(); ++i) {
    const EsdfAnswer a = f.field.distance(points[i]).value();
    REQUIRE(a.has_distance == before[i].has_distance);
    REQUIRE(a.distance_m == before[i].distance_m);
    REQUIRE(a.gradient == before[i].gradient);
    CHECK(a.map_version == 2);
  }

  // A block inside it changes at frame 8: a whole rebuild, seeds and both sweeps.
  VoxelBlock<TsdfVoxel>* inside = nullptr;
  for (int z = 4; z < 12 && inside == nullptr; ++z) {
    for (int y = 4; y < 12 && inside == nullptr; ++y) {
      for (int x = 4; x < 12 && inside == nullptr; ++x) {
        inside = owned.map.find_block(Eigen::Vector3i(x, y, z));
      }
    }
  }
  REQUIRE(inside != nullptr);
  inside->last_updated_frame = 8;
  const EsdfReport changed = f.field.update(owned.map, nullptr, kMu_m, 8, 3);
  CHECK(changed.published);
  CHECK(changed.chunks_reseeded > 0);
  CHECK(changed.cell_steps == 3 * volume);
  CHECK(f.field.published_version() == 3);
  // The same answers (the map's voxels did not change), now from the swept back buffer.
  for (std::size_t i = 0; i < points.size(); ++i) {
    const EsdfAnswer a = f.field.distance(points[i]).value();
    REQUIRE(a.distance_m == before[i].distance_m);
  }
}

TEST_CASE("a budget spreads a rebuild over frames; queries see the old field until it is whole") {
  test::OwnedMap<TsdfVoxel> owned(map_config());
  const Scene scene;
  test::fill_band(owned.map, kMu_m, scene, [](const Eigen::Vector3i&) { return 0; });
  EsdfConfig config = field_config();
  config.max_cell_steps = 20000;
  Field budgeted(config);
  Field whole(field_config());
  REQUIRE(whole.field.flush(owned.map, nullptr, kMu_m, 0, 1).published);
  int frames = 0;
  const Eigen::Vector3f p(-1.0f, -1.0f, -0.5f);
  for (;;) {
    const EsdfReport r = budgeted.field.update(owned.map, nullptr, kMu_m, 0, 1);
    ++frames;
    CHECK(r.cell_steps <= config.max_cell_steps + 512u);
    if (r.published) break;
    CHECK(r.budget_hit);
    CHECK(!budgeted.field.distance(p).value().has_distance);  // nothing published yet
    REQUIRE(frames < 100);
  }
  // 512 chunks seeded and 2 sweeps of 64^3 cells, 20000 a frame (and at most a chunk more).
  CHECK(frames >= 3 * 64 * 64 * 64 / (20000 + 512));
  CHECK(frames <= 3 * 64 * 64 * 64 / 20000 + 1);
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> u(-1.27f, 1.27f);
  for (int i = 0; i < 5000; ++i) {
    const Eigen::Vector3f q(u(rng), u(rng), u(rng));
    REQUIRE(budgeted.field.distance(q).value().distance_m ==
            whole.field.distance(q).value().distance_m);
  }
}

TEST_CASE("a window moved by centre_on is built whole; the old one answers until it is published") {
  test::OwnedMap<TsdfVoxel> owned(map_config());
  const Scene scene;
  test::fill_band(owned.map, kMu_m, scene, [](const Eigen::Vector3i&) { return 0; });
  // 32 cells of 2 voxels: a 1.28 m window in the 2.56 m cube, first towards the floor's low
  // corner, then moved by 10 cells along each axis.
  EsdfConfig config = field_config();
  config.cells_per_side = 32;
  config.centre_W = Eigen::Vector3f(-0.3f, -0.3f, -0.3f);
  config.max_cell_steps = 4000;
  Field f(config);
  // Built at frame 10: the blocks (written at frame 0) count as unchanged since, so the move
  // copies the seeds of the cells both windows hold.
  REQUIRE(f.field.flush(owned.map, nullptr, kMu_m, 10, 1).published);
  const Eigen::Vector3f old_min = f.field.window_min_W();
  const Eigen::Vector3f above_floor(-0.6f, -0.6f, -0.5f);  // 0.3 m over the floor
  const Eigen::Vector3f above_sphere(0.1f, -0.05f, 0.6f);  // 0.1 m over the sphere's top
  const EsdfAnswer floor_before = f.field.distance(above_floor).value();
  REQUIRE(floor_before.has_distance);
  CHECK(floor_before.distance_m == Approx(0.3f).margin(kVoxel_m));
  CHECK_FALSE(f.field.distance(above_sphere).value().has_distance);  // outside the window

  // Non-finite centres change nothing; a new one does, for the next rebuild.
  const Eigen::Vector3f centre_before = f.field.target_centre_W();
  f.field.centre_on(Eigen::Vector3f(std::numeric_limits<float>::quiet_NaN(), 0.0f, 0.0f));
  CHECK(f.field.target_centre_W() == centre_before);
  const Eigen::Vector3f centre(0.1f, 0.1f, 0.1f);
  f.field.centre_on(centre);
  CHECK((f.field.target_centre_W() - centre).cwiseAbs().maxCoeff() <= 2.0f * kVoxel_m);

  // The map did not change, yet the moved window is rebuilt over frames, within the budget:
  // chunks the old window held are copied, shifted (but for a margin at its faces), the others
  // seeded from the map; until then queries see the old window.
  int frames = 0;
  std::uint32_t reseeded = 0;
  for (;;) {
    const EsdfReport r = f.field.update(owned.map, nullptr, kMu_m, 11, 1);
    reseeded += r.chunks_reseeded;
    ++frames;
    REQUIRE(frames < 100);
    if (r.published) break;
    CHECK(r.budget_hit);
    CHECK(f.field.window_min_W() == old_min);
    CHECK(f.field.distance(above_floor).value().distance_m == floor_before.distance_m);
  }
  CHECK(frames > 3);
  CAPTURE(reseeded);
  // 4^3 chunks, moved 10 cells along each axis: the old window gives the cells at least 2 inside
  // its faces, which fill the new window's first 2 chunks along each axis; the other 56 hold
  // cells seeded from the map. A chunk whose copied sites were out of place would be seeded too.
  CHECK(reseeded == 56);
  CHECK((f.field.window_min_W() - (centre - Eigen::Vector3f::Constant(0.64f))).norm() <=
        4.0f * kVoxel_m);
  CHECK_FALSE(f.field.distance(above_floor).value().has_distance);  // left behind
  const EsdfAnswer sphere = f.field.distance(above_sphere).value();
  REQUIRE(sphere.has_distance);
  CHECK(sphere.distance_m == Approx(0.1f).margin(kVoxel_m));
  // Nothing more to do once it is built.
  CHECK(f.field.update(owned.map, nullptr, kMu_m, 12, 1).cell_steps == 0);

  // The same bits as a field built there from the start.
  EsdfConfig there = config;
  there.centre_W = centre;
  Field g(there);
  REQUIRE(g.field.flush(owned.map, nullptr, kMu_m, 0, 1).published);
  REQUIRE(g.field.window_min_W() == f.field.window_min_W());
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0.0f, 1.28f);
  for (int i = 0; i < 5000; ++i) {
    const Eigen::Vector3f q = g.field.window_min_W() + Eigen::Vector3f(u(rng), u(rng), u(rng));
    const EsdfAnswer a = f.field.distance(q).value();
    const EsdfAnswer b = g.field.distance(q).value();
    REQUIRE(a.has_distance == b.has_distance);
    REQUIRE(a.distance_m == b.distance_m);
    REQUIRE(a.lower_bound_m == b.lower_bound_m);
  }
}

TEST_CASE("unknown as obstacle: distances to the nearest unobserved cell too") {
  test::OwnedMap<TsdfVoxel> owned(map_config());
  const Scene scene;
  test::fill_band(owned.map, kMu_m, scene, [](const Eigen::Vector3i&) { return 0; });
  EsdfConfig config = field_config();
  config.unknown_is_obstacle = true;
  Field f(config);
  REQUIRE(f.field.flush(owned.map, nullptr, kMu_m, 0, 1).published);
  // Without free space everything outside the band blocks is unknown: a point in a band block
  // just above the floor is within a block of unknown space.
  const EsdfAnswer a = f.field.distance(Eigen::Vector3f(-1.0f, -1.0f, -0.75f)).value();
  REQUIRE(a.has_distance);
  CHECK(a.distance_m <= 0.05f + kVoxel_m);
}

// FNV-1a over the bits of every answer (has_distance, distance, bound, gradient) on a 41^3 grid
// through the window and a little beyond it.
std::uint64_t answers_digest(const EsdfField& field) {
  std::uint64_t hash = 0xcbf29ce484222325ull;
  auto mix = [&hash](const void* data, std::size_t bytes) {
    const unsigned char* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < bytes; ++i) hash = (hash ^ p[i]) * 0x100000001b3ull;
  };
  for (int z = 0; z <= 40; ++z) {
    for (int y = 0; y <= 40; ++y) {
      for (int x = 0; x <= 40; ++x) {
        const Eigen::Vector3f p =
            Eigen::Vector3f(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z)) *
                0.0657f -
            Eigen::Vector3f::Constant(1.31f);
        const EsdfAnswer a = field.distance(p).value();
        const unsigned char has = a.has_distance ? 1 : 0;
        mix(&has, 1);
        mix(&a.distance_m, sizeof(float));
        mix(&a.lower_bound_m, sizeof(float));
        mix(a.gradient.data(), 3 * sizeof(float));
      }
    }
  }
  return hash;
}

std::string hex(std::uint64_t bits) {
  char text[24];
  std::snprintf(text, sizeof text, "0x%016llx", static_cast<unsigned long long>(bits));
  return text;
}

// The answers over a map of blocks at scales 0-2 (and unallocated space), for each cell size and
// both unknown modes, pinned: the seeding's and the sweeps' shortcuts (a block looked up once a
// row, cells of absent blocks skipped, each cell's distance computed once a slice) and the 5-byte
// cells (a site stored once, at its seed) give the bits of the plain computation with the site in
// every 8-byte cell (pinned before those changes; cells of one voxel were re-pinned when their
// sites moved to a 1/32-cell lattice). Same bits on every architecture, as the map's. Prints what
// it got, for re-pinning after a deliberate change.
TEST_CASE("the field's answers are pinned bits, whatever the cell size and unknown mode") {
  struct Case {
    int cell_voxels;
    bool unknown_is_obstacle;
    std::uint64_t expected;
  };
  test::OwnedMap<MultiresVoxel> owned(map_config());
  Scene scene;
  scene.with_box = true;
  test::fill_band(owned.map, kMu_m, scene,
                  [](const Eigen::Vector3i& b) { return (b.x() + 2 * b.y() + b.z()) % 3; });
  for (const Case c :
       {Case{1, false, 0xfc7f1b2c5dd59eb9ull}, Case{2, false, 0xdc8535cbc3a0dc4full},
        Case{4, false, 0x6b5e874c402fe9eaull}, Case{2, true, 0xb2911ceb760e4663ull}}) {
    CAPTURE(c.cell_voxels, c.unknown_is_obstacle);
    EsdfConfig config = field_config();
    config.cell_voxels = c.cell_voxels;
    config.cells_per_side = c.cell_voxels == 4 ? 32 : 64;
    config.unknown_is_obstacle = c.unknown_is_obstacle;
    Field f(config);
    REQUIRE(f.field.flush(owned.map, nullptr, kMu_m, 0, 1).published);
    const std::uint64_t digest = answers_digest(f.field);
    std::printf("field answers, cell_voxels %d, unknown_is_obstacle %d: %s\n", c.cell_voxels,
                c.unknown_is_obstacle ? 1 : 0, hex(digest).c_str());
    CHECK(hex(digest) == hex(c.expected));
  }
}

TEST_CASE("bad configurations and points are refused") {
  EsdfConfig c = field_config();
  c.cells_per_side = 60;
  CHECK(validate(c, map_config()).code() == StatusCode::invalid_argument);
  c = field_config();
  c.cell_voxels = 3;
  CHECK(validate(c, map_config()).code() == StatusCode::invalid_argument);
  c = field_config();
  c.cells_per_side = 128;  // 256 voxels > the 128 of the cube
  CHECK(validate(c, map_config()).code() == StatusCode::invalid_argument);
  c = field_config();
  c.centre_W = Eigen::Vector3f(0.0f, std::numeric_limits<float>::infinity(), 0.0f);
  CHECK(validate(c, map_config()).code() == StatusCode::invalid_argument);
  for (const float bad :
       {-0.1f, std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity()}) {
    c = field_config();
    c.follow_m = bad;
    CHECK(validate(c, map_config()).code() == StatusCode::invalid_argument);
  }

  // The largest window (1016^3 cells, 10.5 GB) is refused where it cannot be addressed.
  c = field_config();
  c.cells_per_side = 1016;
  c.cell_voxels = 1;
  const MapConfig big = MapConfig::centred(Eigen::Vector3f::Zero(), kVoxel_m, 10, 40000, 40000);
  CHECK(validate(c, big).code() ==
        (sizeof(std::size_t) >= 8 ? StatusCode::ok : StatusCode::invalid_argument));

  Field f(field_config());
  const float nan = std::numeric_limits<float>::quiet_NaN();
  CHECK(f.field.distance(Eigen::Vector3f(nan, 0, 0)).status().code() ==
        StatusCode::invalid_argument);
  std::vector<Eigen::Vector3f> points = {Eigen::Vector3f::Zero(), Eigen::Vector3f(0, nan, 0)};
  std::vector<EsdfAnswer> out(2);
  CHECK(f.field.distances(points.data(), points.size(), out.data()).code() ==
        StatusCode::invalid_argument);
  // Outside the window (and the cube): no distance.
  CHECK(!f.field.distance(Eigen::Vector3f(5.0f, 0.0f, 0.0f)).value().has_distance);
}

}  // namespace
}  // namespace octofuse
