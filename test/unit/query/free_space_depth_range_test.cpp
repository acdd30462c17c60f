// The depth range free space carves with: pixels without depth, the range of a pixel
// rectangle, depths beyond the range, and the silhouettes of nearer objects.

#include "octofuse/query/free_space.hpp"

#include <catch2/catch.hpp>

#include "unit/query/query_support.hpp"

namespace octofuse {
namespace {

TEST_CASE("pixels without depth neither carve nor clear; the rest of the view still carves") {
  Mapper m;
  const AnalyticScene scene = wall_at(kWall_m);
  for (int i = 0; i < 2; ++i) m.fuse(scene);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.5f).state == PointState::free);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.8f).state == PointState::free);
  // A frame with a hole in the middle (no depth there, as on a black or shiny patch).
  scene.render(m.camera, Se3d::Identity(), m.depth);
  for (int v = 50; v < 70; ++v) {
    for (int u = 70; u < 90; ++u) m.depth[static_cast<std::size_t>(v * m.camera.width + u)] = 0.0f;
  }
  ImageView<const float> holed(m.depth.data(), m.camera.width, m.camera.height);
  const FreeSpaceReport report = m.free_space.carve(holed, m.camera, Se3d::Identity(), m.frame++);
  REQUIRE(!report.budget_hit);
  // What was seen free in front of the hole stays free.
  REQUIRE(ask(m, 0.0f, 0.0f, 1.5f).state == PointState::free);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.8f).state == PointState::free);

  // A map that only ever saw the holed frame: free around the hole, never in front of it.
  Mapper fresh;
  fresh.free_space.carve(holed, fresh.camera, Se3d::Identity(), fresh.frame++);
  REQUIRE(ask(fresh, 0.0f, 0.0f, 1.5f).state == PointState::unknown);
  // 30 pixels off the hole's edge at 1.5 m (about 0.35 m beside the axis).
  REQUIRE(ask(fresh, 0.55f, 0.0f, 1.5f).state == PointState::free);
  REQUIRE(ask(fresh, 0.0f, 0.45f, 1.5f).state == PointState::free);
}

TEST_CASE("the depth range of any pixel rectangle is the brute-force one") {
  // Random depths, holes and beyond-range pixels; every rectangle's range from the range table
  // equals the one computed pixel by pixel.
  Mapper m;
  const int w = m.camera.width;
  const int h = m.camera.height;
  const float range_end_m = 3.5f;
  std::vector<float> depth(static_cast<std::size_t>(w) * static_cast<std::size_t>(h));
  std::vector<std::uint8_t> beyond(depth.size(), 0);
  std::uint32_t state = 12345u;
  auto next = [&state]() {
    state = state * 1664525u + 1013904223u;
    return state >> 8;
  };
  for (std::size_t i = 0; i < depth.size(); ++i) {
    const std::uint32_t r = next() % 100u;
    depth[i] = r < 10 ? 0.0f : 0.3f + static_cast<float>(next() % 3000u) * 0.001f;
    beyond[i] = r < 5 ? 1 : 0;
  }
  const ImageView<const float> depth_view(depth.data(), w, h);
  const ImageView<const std::uint8_t> beyond_view(beyond.data(), w, h);
  m.free_space.carve(depth_view, m.camera, Se3d::Identity(), m.frame++, beyond_view, range_end_m);
  for (int trial = 0; trial < 3000; ++trial) {
    int u0 = static_cast<int>(next() % static_cast<std::uint32_t>(w));
    int v0 = static_cast<int>(next() % static_cast<std::uint32_t>(h));
    // Mostly small rectangles, some up to the whole image.
    const std::uint32_t max_side = trial % 4 == 0 ? 200u : 24u;
    int u1 = u0 + static_cast<int>(next() % max_side);
    int v1 = v0 + static_cast<int>(next() % max_side);
    const FreeSpace::PixelRange got = m.free_space.pixel_range(u0, v0, u1, v1);
    u1 = std::min(u1, w - 1);
    v1 = std::min(v1, h - 1);
    float lo = FreeSpace::kNoDepth;
    float hi = 0.0f;
    bool invalid = false;
    for (int v = v0; v <= v1; ++v) {
      for (int u = u0; u <= u1; ++u) {
        const std::size_t i =
            static_cast<std::size_t>(v) * static_cast<std::size_t>(w) + static_cast<std::size_t>(u);
        if (depth[i] > 0.0f) {
          lo = std::min(lo, depth[i]);
          hi = std::max(hi, depth[i]);
        } else if (beyond[i] != 0) {
          lo = std::min(lo, range_end_m);
        } else {
          invalid = true;
        }
      }
    }
    REQUIRE(got.lo_m == lo);
    REQUIRE(got.hi_m == hi);
    REQUIRE(got.any_invalid == invalid);
  }
  // Clipped to the image; wholly outside it nothing is measured.
  const FreeSpace::PixelRange all = m.free_space.pixel_range(-5, -5, w + 5, h + 5);
  REQUIRE(all.any_invalid);
  REQUIRE(all.hi_m > 0.0f);
  const FreeSpace::PixelRange outside = m.free_space.pixel_range(w, 0, w + 3, 4);
  REQUIRE(outside.lo_m == FreeSpace::kNoDepth);
  REQUIRE(outside.hi_m == 0.0f);
}

TEST_CASE("pixels measured beyond the range carve in front of its end and clear nothing behind") {
  // Every pixel saw a surface beyond the range (depth 0, marked beyond): free out to the range's
  // end less the clearance, unknown past it.
  const float range_end_m = 1.2f;
  std::vector<float> no_depth;
  std::vector<std::uint8_t> all_beyond;
  {
    Mapper m;
    no_depth.assign(
        static_cast<std::size_t>(m.camera.width) * static_cast<std::size_t>(m.camera.height), 0.0f);
    all_beyond.assign(no_depth.size(), 1);
    const ImageView<const float> depth(no_depth.data(), m.camera.width, m.camera.height);
    const ImageView<const std::uint8_t> beyond(all_beyond.data(), m.camera.width, m.camera.height);
    // Without the mask the frame shows nothing.
    m.free_space.carve(depth, m.camera, Se3d::Identity(), m.frame++);
    REQUIRE(ask(m, 0.0f, 0.0f, 0.8f).state == PointState::unknown);
    const FreeSpaceReport report =
        m.free_space.carve(depth, m.camera, Se3d::Identity(), m.frame++, beyond, range_end_m);
    REQUIRE(!report.budget_hit);
    REQUIRE(report.marked_free > 0);
    REQUIRE(ask(m, 0.0f, 0.0f, 0.8f).state == PointState::free);
    REQUIRE(ask(m, 0.1f, -0.1f, 1.0f).state == PointState::free);
    // Nothing free at or past the range's end less the clearance.
    for (float z = 1.2f - 0.5f * kMu_m; z < 3.0f; z += 0.01f) {
      REQUIRE(ask(m, 0.0f, 0.0f, z).state == PointState::unknown);
    }
    // A mask whose size is not the image's is ignored.
    Mapper other;
    const ImageView<const std::uint8_t> wrong(all_beyond.data(), m.camera.width - 1,
                                              m.camera.height);
    other.free_space.carve(depth, other.camera, Se3d::Identity(), other.frame++, wrong,
                           range_end_m);
    REQUIRE(ask(other, 0.0f, 0.0f, 0.8f).state == PointState::unknown);
  }
  // Free space seen earlier behind the range's end: a surface measured there would clear it (it
  // lies within the occlusion depth behind), a ray that went beyond the range does not.
  Mapper m;
  const AnalyticScene scene = wall_at(kWall_m);
  for (int i = 0; i < 2; ++i) m.fuse(scene);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.5f).state == PointState::free);
  const ImageView<const float> depth(no_depth.data(), m.camera.width, m.camera.height);
  const ImageView<const std::uint8_t> beyond(all_beyond.data(), m.camera.width, m.camera.height);
  const float end_m = 1.4f;
  m.free_space.carve(depth, m.camera, Se3d::Identity(), m.frame++, beyond, end_m);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.5f).state == PointState::free);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.8f).state == PointState::free);
  std::vector<float> flat(no_depth.size(), end_m);
  const ImageView<const float> surface(flat.data(), m.camera.width, m.camera.height);
  m.free_space.carve(surface, m.camera, Se3d::Identity(), m.frame++);
  REQUIRE(ask(m, 0.0f, 0.0f, 1.5f).state == PointState::unknown);
}

TEST_CASE("exact silhouettes: a nearer object's silhouette neither clears free air nor hides it") {
  // The wall at 2 m, then a ball 0.8 m in front of the camera. The ball's shadow at 1.5 m
  // reaches about 0.19 m from the axis. Its depth lies far (more than occlusion_clear_m) in front
  // of the air there, so it is no evidence about that air either way: octants that see the
  // ball's edge and the wall behind are settled pixel by pixel.
  AnalyticScene ball = wall_at(kWall_m);
  ball.spheres.push_back({Eigen::Vector3d(0.0, 0.0, 0.8), 0.1});
  FreeSpaceConfig exact;
  exact.exact_silhouettes = true;
  Mapper fresh(exact);
  fresh.fuse(ball);
  fresh.fuse(ball);
  // Seen only with the ball: free from a leaf's width beside the shadow to short of the image's
  // border, unknown in the shadow.
  for (float x = 0.34f; x <= 0.58f; x += 0.02f) {
    INFO("x " << x);
    REQUIRE(ask(fresh, x, 0.0f, 1.5f).state == PointState::free);
    REQUIRE(ask(fresh, -x, 0.0f, 1.5f).state == PointState::free);
    REQUIRE(ask(fresh, 0.0f, x, 1.5f).state == PointState::free);
  }
  for (float z = 1.1f; z < 1.8f; z += 0.02f) {
    INFO("z " << z);
    REQUIRE(ask(fresh, 0.0f, 0.0f, z).state == PointState::unknown);
    REQUIRE(ask(fresh, 0.05f, -0.05f, z).state == PointState::unknown);
  }
  // Seen free first, then the ball passes in front: the air across its silhouette stays free.
  Mapper m(exact);
  const AnalyticScene wall = wall_at(kWall_m);
  m.fuse(wall);
  m.fuse(wall);
  for (float x = 0.0f; x <= 0.4f; x += 0.02f) {
    REQUIRE(ask(m, x, 0.0f, 1.5f).state == PointState::free);
  }
  m.fuse(ball);
  m.fuse(ball);
  for (float x = 0.0f; x <= 0.4f; x += 0.02f) {
    INFO("x " << x);
    REQUIRE(ask(m, x, 0.0f, 1.5f).state == PointState::free);
    REQUIRE(ask(m, 0.0f, -x, 1.5f).state == PointState::free);
  }
  // The ball itself and the air just around it are not free.
  REQUIRE(ask(m, 0.0f, 0.0f, 0.8f).state != PointState::free);
  REQUIRE(ask(m, 0.0f, 0.0f, 0.69f).state != PointState::free);
  REQUIRE(ask(m, 0.11f, 0.0f, 0.8f).state != PointState::free);
}

}  // namespace
}  // namespace octofuse
