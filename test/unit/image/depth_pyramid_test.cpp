#include "octofuse/image/depth_pyramid.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "support/aligned_buffer.hpp"
#include "support/alloc_counter.hpp"
#include "support/camera.hpp"

namespace octofuse {
namespace {

constexpr float kDepthTolerance_m = 1e-6f;
constexpr float kVertexTolerance_m = 1e-5f;
constexpr float kNormalTolerance = 1e-4f;

// Owns a 64-byte aligned buffer of exactly the size ArenaSizer reports for the preprocessor.
struct PreprocessorFixture {
  explicit PreprocessorFixture(const PreprocessConfig& config, int width, int height)
      : memory(bytes_for(config, width, height)), bytes(memory.bytes()) {
    REQUIRE(pre.reserve(memory.arena(), config, width, height).ok());
  }
  static std::size_t bytes_for(const PreprocessConfig& config, int width, int height) {
    ArenaSizer sizer;
    REQUIRE(DepthPreprocessor().reserve(sizer, config, width, height).ok());
    return sizer.bytes_used();
  }
  test::ArenaBuffer memory;
  DepthPreprocessor pre;
  std::size_t bytes = 0;
};

TEST_CASE("ArenaSizer gives the exact bytes the preprocessor takes") {
  for (const bool bilateral : {false, true}) {
    PreprocessConfig config;
    config.bilateral = bilateral;
    PreprocessorFixture fixture(config, 640, 480);
    CHECK(fixture.memory.arena().bytes_used() == fixture.bytes);
    CHECK(fixture.bytes >= 320u * 240u * (4u + 12u + 12u));

    // One byte short fails cleanly.
    std::vector<std::uint8_t> short_storage(fixture.bytes - 1 + kArenaAlignment);
    LinearArena too_small(
        reinterpret_cast<void*>(
            align_up(reinterpret_cast<std::uintptr_t>(short_storage.data()), kArenaAlignment)),
        fixture.bytes - 1);
    DepthPreprocessor other;
    CHECK(other.reserve(too_small, config, 640, 480) == StatusCode::resource_exhausted);
  }
}

TEST_CASE("reserve and process reject bad configs, sizes and cameras") {
  PreprocessConfig config;
  ArenaSizer sizer;
  DepthPreprocessor pre;
  config.downsample_factor = 3;
  CHECK(pre.reserve(sizer, config, 640, 480) == StatusCode::invalid_argument);
  config.downsample_factor = 2;
  CHECK(pre.reserve(sizer, config, 644, 480) == StatusCode::invalid_argument);  // 644 / 8
  config.bilateral = true;
  config.bilateral_sigma_range_m = 0.0f;
  CHECK(pre.reserve(sizer, config, 640, 480) == StatusCode::invalid_argument);

  std::vector<float> depth(640 * 480, 1.0f);
  const WorkerTeam team(1);
  CHECK(pre.process(ImageView<const float>(depth.data(), 640, 480), test::vga_camera(), team) ==
        StatusCode::failed_precondition);

  PreprocessorFixture fixture(PreprocessConfig{}, 640, 480);
  CHECK(fixture.pre.process(ImageView<const float>(depth.data(), 320, 480), test::vga_camera(),
                            team) == StatusCode::invalid_argument);
  PinholeCamera bad = test::vga_camera();
  bad.fx = std::numeric_limits<float>::quiet_NaN();
  CHECK(fixture.pre.process(ImageView<const float>(depth.data(), 640, 480), bad, team) ==
        StatusCode::invalid_argument);
}

TEST_CASE("pyramid depth values on a small image, by hand") {
  // Level 0 (4 x 4) as designed; every input 2 x 2 block is constant except the first, which
  // holds an outlier the robust average drops.
  const float level0[4][4] = {{1.00f, 1.04f, 3.00f, 3.00f},
                              {1.02f, 0.00f, 3.00f, 3.20f},
                              {2.00f, 2.00f, 0.00f, 0.00f},
                              {2.00f, 2.50f, 0.00f, 0.00f}};
  std::vector<float> input(8 * 8);
  for (int y = 0; y < 8; ++y) {
    for (int x = 0; x < 8; ++x) input[y * 8 + x] = level0[y / 2][x / 2];
  }
  input[1 * 8 + 1] = 5.0f;  // outlier in block (0, 0)

  PinholeCamera camera;
  camera.fx = 10.0f;
  camera.fy = 10.0f;
  camera.cx = 3.5f;
  camera.cy = 3.5f;
  camera.width = 8;
  camera.height = 8;
  PreprocessorFixture fixture(PreprocessConfig{}, 8, 8);
  const WorkerTeam team(1);
  REQUIRE(fixture.pre.process(ImageView<const float>(input.data(), 8, 8), camera, team).ok());
  const DepthPyramid& p = fixture.pre.pyramid();

  REQUIRE(p.depth_m[0].width == 4);
  for (int y = 0; y < 4; ++y) {
    for (int x = 0; x < 4; ++x) {
      INFO("x " << x << " y " << y);
      CHECK(p.depth_m[0](x, y) == Approx(level0[y][x]).margin(kDepthTolerance_m));
    }
  }
  // Level 1: {1.00, 1.04, 1.02, hole} -> median 1.02 -> mean of all three; {3, 3, 3, 3.2} -> 3.2
  // is outside the 0.1 m band; {2, 2, 2, 2.5} -> 2; all holes -> hole.
  REQUIRE(p.depth_m[1].width == 2);
  CHECK(p.depth_m[1](0, 0) == Approx((1.00f + 1.02f + 1.04f) / 3.0f).margin(kDepthTolerance_m));
  CHECK(p.depth_m[1](1, 0) == 3.0f);
  CHECK(p.depth_m[1](0, 1) == 2.0f);
  CHECK(p.depth_m[1](1, 1) == 0.0f);
  // Level 2: {1.02, 3, 2, hole} -> median 2, the others are outside the band.
  REQUIRE(p.depth_m[2].width == 1);
  CHECK(p.depth_m[2](0, 0) == 2.0f);

  // Cameras follow the pixel-centre convention of PinholeCamera::downsampled.
  CHECK(p.camera[0].fx == 5.0f);
  CHECK(p.camera[0].cx == 1.5f);
  CHECK(p.camera[1].fx == 2.5f);
  CHECK(p.camera[1].cx == 0.5f);
  CHECK(p.camera[2].cx == 0.0f);
  // Vertices back-project with each level's camera; holes have none.
  const Eigen::Vector3f expected = p.camera[1].back_project(0.0f, 1.0f, 2.0f);
  CHECK((p.vertices_C[1](0, 1) - expected).norm() <= kVertexTolerance_m);
  CHECK(p.vertices_C[1](1, 1) == Eigen::Vector3f::Zero());
  CHECK(p.normals_C[1](1, 1) == Eigen::Vector3f::Zero());
}

TEST_CASE("a fronto-parallel wall gives exact depth, vertices and normals at every level") {
  for (const bool bilateral : {false, true}) {
    PreprocessConfig config;
    config.bilateral = bilateral;
    PreprocessorFixture fixture(config, 640, 480);
    constexpr float kWall_m = 1.5f;
    std::vector<float> depth(640 * 480, kWall_m);
    const WorkerTeam team(1);
    REQUIRE(fixture.pre
                .process(ImageView<const float>(depth.data(), 640, 480), test::vga_camera(), team)
                .ok());
    const DepthPyramid& p = fixture.pre.pyramid();
    for (int level = 0; level < kPyramidLevels; ++level) {
      const int w = 320 >> level;
      const int h = 240 >> level;
      REQUIRE(p.depth_m[level].width == w);
      REQUIRE(p.depth_m[level].height == h);
      int wrong = 0;
      for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) {
          const bool border = x == 0 || y == 0 || x == w - 1 || y == h - 1;
          const Eigen::Vector3f v = p.vertices_C[level](x, y);
          const Eigen::Vector3f n = p.normals_C[level](x, y);
          const Eigen::Vector3f v_expected =
              p.camera[level].back_project(static_cast<float>(x), static_cast<float>(y), kWall_m);
          if (std::abs(p.depth_m[level](x, y) - kWall_m) > kDepthTolerance_m) ++wrong;
          if ((v - v_expected).norm() > kVertexTolerance_m) ++wrong;
          if (border ? n != Eigen::Vector3f::Zero()
                     : (n - Eigen::Vector3f(0.0f, 0.0f, -1.0f)).norm() > kNormalTolerance) {
            ++wrong;
          }
        }
      }
      INFO("level " << level << " bilateral " << bilateral);
      CHECK(wrong == 0);
    }
  }
}

TEST_CASE("invalid input pixels stay invalid through the pyramid") {
  // The left 256 input columns have no depth: level l has (256 / 2 / 2^l) empty columns.
  std::vector<float> depth(640 * 480, 2.0f);
  for (int y = 0; y < 480; ++y) {
    for (int x = 0; x < 256; ++x) depth[y * 640 + x] = 0.0f;
  }
  PreprocessConfig config;
  config.bilateral = true;
  PreprocessorFixture fixture(config, 640, 480);
  const WorkerTeam team(1);
  REQUIRE(
      fixture.pre.process(ImageView<const float>(depth.data(), 640, 480), test::vga_camera(), team)
          .ok());
  const DepthPyramid& p = fixture.pre.pyramid();
  for (int level = 0; level < kPyramidLevels; ++level) {
    const int empty_columns = 128 >> level;
    int wrong = 0;
    for (int y = 0; y < p.depth_m[level].height; ++y) {
      for (int x = 0; x < p.depth_m[level].width; ++x) {
        if (x < empty_columns) {
          wrong += p.depth_m[level](x, y) != 0.0f;
          wrong += p.vertices_C[level](x, y) != Eigen::Vector3f::Zero();
          wrong += p.normals_C[level](x, y) != Eigen::Vector3f::Zero();
        } else {
          wrong += p.depth_m[level](x, y) != 2.0f;
        }
      }
    }
    INFO("level " << level);
    CHECK(wrong == 0);
    CHECK(p.normals_C[level](empty_columns, 10) == Eigen::Vector3f::Zero());  // next to the hole
  }
}

std::vector<float> noisy_slanted_depth(std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> noise_m(-0.01f, 0.01f);
  std::uniform_int_distribution<int> hole(0, 19);
  std::vector<float> depth(640 * 480);
  for (int y = 0; y < 480; ++y) {
    for (int x = 0; x < 640; ++x) {
      const float d = 1.0f + 0.003f * static_cast<float>(x) + (x > 400 ? 0.5f : 0.0f);
      depth[y * 640 + x] = hole(rng) == 0 ? 0.0f : d + noise_m(rng);
    }
  }
  return depth;
}

TEST_CASE("process is bit-identical for 1 and 2 workers and allocates nothing") {
  PreprocessConfig config;
  config.bilateral = true;
  const std::vector<float> depth = noisy_slanted_depth(42);
  PreprocessorFixture one(config, 640, 480);
  PreprocessorFixture two(config, 640, 480);
  const WorkerTeam team1(1);
  const WorkerTeam team2(2);
  const ImageView<const float> input(depth.data(), 640, 480);
  {
    test::AllocationScope scope;
    REQUIRE(one.pre.process(input, test::vga_camera(), team1).ok());
    REQUIRE(two.pre.process(input, test::vga_camera(), team2).ok());
    CHECK(scope.allocations() == 0);
  }
  const DepthPyramid& a = one.pre.pyramid();
  const DepthPyramid& b = two.pre.pyramid();
  for (int level = 0; level < kPyramidLevels; ++level) {
    const std::size_t n = a.depth_m[level].pixel_count();
    INFO("level " << level);
    CHECK(std::memcmp(a.depth_m[level].data, b.depth_m[level].data, n * sizeof(float)) == 0);
    CHECK(std::memcmp(a.vertices_C[level].data, b.vertices_C[level].data,
                      n * sizeof(Eigen::Vector3f)) == 0);
    CHECK(std::memcmp(a.normals_C[level].data, b.normals_C[level].data,
                      n * sizeof(Eigen::Vector3f)) == 0);
  }
}

TEST_CASE("garbage depth (NaN, infinities, negatives, huge values) gives a clean pyramid") {
  std::mt19937 rng(99);
  const float specials[] = {std::numeric_limits<float>::quiet_NaN(),
                            std::numeric_limits<float>::infinity(),
                            -std::numeric_limits<float>::infinity(),
                            -1.0f,
                            0.0f,
                            1e30f,
                            std::numeric_limits<float>::denorm_min(),
                            std::numeric_limits<float>::max()};
  std::uniform_int_distribution<int> pick(0, 15);
  std::uniform_real_distribution<float> depth_m(0.3f, 5.0f);
  std::vector<float> depth(640 * 480);
  for (float& d : depth) {
    const int k = pick(rng);
    d = k < 8 ? specials[k] : depth_m(rng);
  }
  PreprocessConfig config;
  config.bilateral = true;
  PreprocessorFixture fixture(config, 640, 480);
  REQUIRE(fixture.pre
              .process(ImageView<const float>(depth.data(), 640, 480), test::vga_camera(),
                       WorkerTeam(1))
              .ok());
  const DepthPyramid& p = fixture.pre.pyramid();
  for (int level = 0; level < kPyramidLevels; ++level) {
    int bad = 0;
    for (int y = 0; y < p.depth_m[level].height; ++y) {
      for (int x = 0; x < p.depth_m[level].width; ++x) {
        const float d = p.depth_m[level](x, y);
        bad += !(d == 0.0f || valid_depth(d));
        bad += !p.vertices_C[level](x, y).allFinite();
        const Eigen::Vector3f n = p.normals_C[level](x, y);
        bad += !(n.isZero(0.0f) || std::abs(n.norm() - 1.0f) < kNormalTolerance);
      }
    }
    INFO("level " << level);
    CHECK(bad == 0);
  }
}

}  // namespace
}  // namespace octofuse
