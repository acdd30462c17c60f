#include "octofuse/image/depth_filters.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "support/analytic_scene.hpp"

namespace octofuse {
namespace {

constexpr float kDepthTolerance_m = 1e-6f;
constexpr float kVertexTolerance_m = 1e-6f;
constexpr float kNormalTolerance = 1e-4f;  // unit vector components

ImageView<const float> view(const std::vector<float>& pixels, int width, int height) {
  return ImageView<const float>(pixels.data(), width, height);
}

TEST_CASE("downsample_depth by 2 averages the valid samples near the block median") {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  // Four 2x2 blocks side by side.
  // block 0: three valid samples within the band, one hole
  // block 1: a depth edge, two near and two far samples: the near side wins (lower median)
  // block 2: no valid sample
  // block 3: one valid sample among NaN, infinity and a negative value
  const std::vector<float> in = {
      1.00f, 1.02f, 1.0f, 3.0f, 0.0f, 0.0f, 2.0f, nan,  //
      1.04f, 0.00f, 1.0f, 3.0f, 0.0f, 0.0f, inf,  -1.0f,
  };
  std::vector<float> out(4, -7.0f);
  const WorkerTeam team(1);
  REQUIRE(downsample_depth(view(in, 8, 2), ImageView<float>(out.data(), 4, 1), 2, 0.1f, team).ok());
  CHECK(out[0] == Approx((1.00f + 1.02f + 1.04f) / 3.0f).margin(kDepthTolerance_m));
  CHECK(out[1] == 1.0f);
  CHECK(out[2] == 0.0f);
  CHECK(out[3] == 2.0f);
}

TEST_CASE("downsample_depth by 4 drops an outlier and by 1 sanitises") {
  std::vector<float> in(16, 2.0f);
  in[5] = 5.0f;
  in[10] = 0.0f;
  float out = 0.0f;
  const WorkerTeam team(1);
  REQUIRE(downsample_depth(view(in, 4, 4), ImageView<float>(&out, 1, 1), 4, 0.1f, team).ok());
  CHECK(out == 2.0f);

  const std::vector<float> raw = {1.5f, -2.0f, std::numeric_limits<float>::quiet_NaN(), 0.25f};
  std::vector<float> copy(4, -1.0f);
  REQUIRE(
      downsample_depth(view(raw, 2, 2), ImageView<float>(copy.data(), 2, 2), 1, 0.1f, team).ok());
  CHECK(copy == std::vector<float>{1.5f, 0.0f, 0.0f, 0.25f});
}

TEST_CASE("downsample_depth rejects bad arguments and leaves the output alone") {
  std::vector<float> in(16, 1.0f);
  std::vector<float> out(4, -1.0f);
  const WorkerTeam team(1);
  const ImageView<float> out_view(out.data(), 2, 2);
  CHECK(downsample_depth(view(in, 4, 4), out_view, 3, 0.1f, team) == StatusCode::invalid_argument);
  CHECK(downsample_depth(view(in, 4, 4), out_view, 4, 0.1f, team) == StatusCode::invalid_argument);
  CHECK(downsample_depth(view(in, 4, 4), out_view, 2, -0.1f, team) == StatusCode::invalid_argument);
  CHECK(downsample_depth(ImageView<const float>(), out_view, 2, 0.1f, team) ==
        StatusCode::invalid_argument);
  CHECK(out == std::vector<float>(4, -1.0f));
}

TEST_CASE("bilateral_filter keeps a step edge and leaves holes as holes") {
  constexpr int kW = 12;
  constexpr int kH = 7;
  std::vector<float> in(kW * kH);
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) in[y * kW + x] = x < kW / 2 ? 1.0f : 2.0f;
  }
  in[3 * kW + 2] = 0.0f;  // a hole on the near side
  std::vector<float> out(in.size(), -1.0f);
  const WorkerTeam team(1);
  REQUIRE(bilateral_filter(view(in, kW, kH), ImageView<float>(out.data(), kW, kH), 4.0f, 0.1f, team)
              .ok());
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      INFO("x " << x << " y " << y);
      const float expected = in[y * kW + x];
      CHECK(out[y * kW + x] == Approx(expected).margin(kDepthTolerance_m));
    }
  }
  CHECK(out[3 * kW + 2] == 0.0f);
}

TEST_CASE("bilateral_filter weights a bump by space and range") {
  constexpr int kW = 9;
  constexpr int kH = 9;
  constexpr float kSigmaSpace_px = 4.0f;
  constexpr float kSigmaRange_m = 0.1f;
  constexpr float kBump_m = 0.01f;
  std::vector<float> in(kW * kH, 1.0f);
  in[4 * kW + 4] = 1.0f + kBump_m;
  std::vector<float> out(in.size());
  const WorkerTeam team(1);
  REQUIRE(bilateral_filter(view(in, kW, kH), ImageView<float>(out.data(), kW, kH), kSigmaSpace_px,
                           kSigmaRange_m, team)
              .ok());
  // Centre: itself with weight 1, its 24 neighbours at 1 m with spatial times range weights.
  double sum = 1.0 + kBump_m;
  double weights = 1.0;
  const double w_range =
      std::exp(-double(kBump_m) * kBump_m / (2.0 * kSigmaRange_m * kSigmaRange_m));
  for (int dy = -2; dy <= 2; ++dy) {
    for (int dx = -2; dx <= 2; ++dx) {
      if (dx == 0 && dy == 0) continue;
      const double w =
          std::exp(-(dx * dx + dy * dy) / (2.0 * kSigmaSpace_px * kSigmaSpace_px)) * w_range;
      sum += w * 1.0;
      weights += w;
    }
  }
  CHECK(out[4 * kW + 4] == Approx(sum / weights).margin(kDepthTolerance_m));
  CHECK(out[4 * kW + 4] < 1.0f + kBump_m);
  CHECK(out[4 * kW + 4] > 1.0f);
  CHECK(out[3 * kW + 3] > 1.0f);  // the bump lifts a neighbour a little
  CHECK(out[0] == 1.0f);          // but not a pixel outside the 5 x 5 window
  CHECK(bilateral_filter(view(in, kW, kH), ImageView<float>(out.data(), kW, kH - 1), 4.0f, 0.1f,
                         team) == StatusCode::invalid_argument);
}

PinholeCamera small_camera(int width, int height) {
  PinholeCamera camera;
  camera.fx = 50.0f;
  camera.fy = 55.0f;
  camera.cx = 0.5f * static_cast<float>(width - 1);
  camera.cy = 0.5f * static_cast<float>(height - 1) + 0.25f;
  camera.width = width;
  camera.height = height;
  return camera;
}

TEST_CASE("depth_to_vertices back-projects valid pixels and zeroes holes") {
  const PinholeCamera camera = small_camera(6, 4);
  std::vector<float> depth(24, 2.0f);
  depth[7] = 0.0f;
  std::vector<Eigen::Vector3f> vertices(24, Eigen::Vector3f::Constant(9.0f));
  const WorkerTeam team(1);
  REQUIRE(depth_to_vertices(view(depth, 6, 4), camera,
                            ImageView<Eigen::Vector3f>(vertices.data(), 6, 4), team)
              .ok());
  const Eigen::Vector3f expected((4.0f - camera.cx) * 2.0f / camera.fx,
                                 (2.0f - camera.cy) * 2.0f / camera.fy, 2.0f);
  CHECK((vertices[2 * 6 + 4] - expected).norm() <= kVertexTolerance_m);
  CHECK(vertices[7] == Eigen::Vector3f::Zero());
  CHECK(depth_to_vertices(view(depth, 6, 4), small_camera(6, 5),
                          ImageView<Eigen::Vector3f>(vertices.data(), 6, 4),
                          team) == StatusCode::invalid_argument);
}

TEST_CASE("normals of a plane are exact and face the camera") {
  constexpr int kW = 20;
  constexpr int kH = 16;
  const PinholeCamera camera = small_camera(kW, kH);
  const Eigen::Vector3d n_C = Eigen::Vector3d(0.2, -0.3, -1.0).normalized();
  const double offset_m = n_C.dot(Eigen::Vector3d(0.0, 0.0, 2.0));
  test::AnalyticScene plane;
  plane.planes.push_back({n_C, offset_m});
  const std::vector<float> depth = plane.render(camera, Se3d::Identity());
  std::vector<Eigen::Vector3f> vertices(kW * kH);
  std::vector<Eigen::Vector3f> normals(kW * kH, Eigen::Vector3f::Constant(9.0f));
  const WorkerTeam team(1);
  REQUIRE(depth_to_vertices(view(depth, kW, kH), camera,
                            ImageView<Eigen::Vector3f>(vertices.data(), kW, kH), team)
              .ok());
  REQUIRE(vertices_to_normals(view(depth, kW, kH),
                              ImageView<const Eigen::Vector3f>(vertices.data(), kW, kH), 0.1f,
                              ImageView<Eigen::Vector3f>(normals.data(), kW, kH), team)
              .ok());
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      INFO("x " << x << " y " << y);
      const Eigen::Vector3f& n = normals[y * kW + x];
      if (x == 0 || y == 0 || x == kW - 1 || y == kH - 1) {
        CHECK(n == Eigen::Vector3f::Zero());
      } else {
        CHECK((n - n_C.cast<float>()).norm() <= kNormalTolerance);
      }
    }
  }
}

TEST_CASE("normals are invalid next to holes and across depth jumps") {
  constexpr int kW = 10;
  constexpr int kH = 8;
  const PinholeCamera camera = small_camera(kW, kH);
  std::vector<float> depth(kW * kH, 1.0f);
  for (int y = 0; y < kH; ++y) {
    for (int x = 6; x < kW; ++x) depth[y * kW + x] = 1.5f;  // a step between x = 5 and 6
  }
  depth[3 * kW + 2] = 0.0f;  // a hole at (2, 3)
  std::vector<Eigen::Vector3f> vertices(kW * kH);
  std::vector<Eigen::Vector3f> normals(kW * kH);
  const WorkerTeam team(1);
  REQUIRE(depth_to_vertices(view(depth, kW, kH), camera,
                            ImageView<Eigen::Vector3f>(vertices.data(), kW, kH), team)
              .ok());
  REQUIRE(vertices_to_normals(view(depth, kW, kH),
                              ImageView<const Eigen::Vector3f>(vertices.data(), kW, kH), 0.1f,
                              ImageView<Eigen::Vector3f>(normals.data(), kW, kH), team)
              .ok());
  auto n_at = [&](int x, int y) { return normals[y * kW + x]; };
  CHECK(n_at(2, 3) == Eigen::Vector3f::Zero());  // the hole itself
  CHECK(n_at(1, 3) == Eigen::Vector3f::Zero());  // its four neighbours
  CHECK(n_at(3, 3) == Eigen::Vector3f::Zero());
  CHECK(n_at(2, 2) == Eigen::Vector3f::Zero());
  CHECK(n_at(2, 4) == Eigen::Vector3f::Zero());
  CHECK(n_at(5, 5) == Eigen::Vector3f::Zero());  // either side of the step
  CHECK(n_at(6, 5) == Eigen::Vector3f::Zero());
  CHECK((n_at(3, 5) - Eigen::Vector3f(0.0f, 0.0f, -1.0f)).norm() <= kNormalTolerance);
  CHECK((n_at(7, 5) - Eigen::Vector3f(0.0f, 0.0f, -1.0f)).norm() <= kNormalTolerance);
}

TEST_CASE("every filter gives bit-identical output for 1 and 2 workers") {
  constexpr int kW = 64;
  constexpr int kH = 48;
  std::mt19937 rng(1234);
  std::uniform_real_distribution<float> noise_m(-0.02f, 0.02f);
  std::uniform_int_distribution<int> hole_dist(0, 9);
  std::vector<float> in(kW * kH);
  for (int y = 0; y < kH; ++y) {  // a slanted noisy plane with 10 % holes
    for (int x = 0; x < kW; ++x) {
      const float d = 1.5f + 0.02f * static_cast<float>(x) + 0.01f * static_cast<float>(y);
      in[y * kW + x] = hole_dist(rng) == 0 ? 0.0f : d + noise_m(rng);
    }
  }
  const PinholeCamera camera = small_camera(kW / 2, kH / 2);

  struct Outputs {
    std::vector<float> half = std::vector<float>(kW * kH / 4);
    std::vector<float> filtered = std::vector<float>(kW * kH / 4);
    std::vector<Eigen::Vector3f> vertices = std::vector<Eigen::Vector3f>(kW * kH / 4);
    std::vector<Eigen::Vector3f> normals = std::vector<Eigen::Vector3f>(kW * kH / 4);
  };
  auto run = [&](int workers) {
    const WorkerTeam team(workers);
    Outputs o;
    const int w = kW / 2;
    const int h = kH / 2;
    REQUIRE(downsample_depth(view(in, kW, kH), ImageView<float>(o.half.data(), w, h), 2, 0.1f, team)
                .ok());
    REQUIRE(bilateral_filter(view(o.half, w, h), ImageView<float>(o.filtered.data(), w, h), 4.0f,
                             0.1f, team)
                .ok());
    REQUIRE(depth_to_vertices(view(o.filtered, w, h), camera,
                              ImageView<Eigen::Vector3f>(o.vertices.data(), w, h), team)
                .ok());
    REQUIRE(vertices_to_normals(view(o.filtered, w, h),
                                ImageView<const Eigen::Vector3f>(o.vertices.data(), w, h), 0.5f,
                                ImageView<Eigen::Vector3f>(o.normals.data(), w, h), team)
                .ok());
    return o;
  };
  const Outputs one = run(1);
  const Outputs two = run(2);
  CHECK(std::memcmp(one.half.data(), two.half.data(), one.half.size() * sizeof(float)) == 0);
  CHECK(std::memcmp(one.filtered.data(), two.filtered.data(),
                    one.filtered.size() * sizeof(float)) == 0);
  CHECK(std::memcmp(one.vertices.data(), two.vertices.data(),
                    one.vertices.size() * sizeof(Eigen::Vector3f)) == 0);
  CHECK(std::memcmp(one.normals.data(), two.normals.data(),
                    one.normals.size() * sizeof(Eigen::Vector3f)) == 0);
}

// The per-pixel code the filters were first written as: the branch-free loops must give its bits.
float reference_downsample_pixel(const std::vector<float>& in, int in_width, int x, int y,
                                 float band_m) {
  float samples[4];
  int n = 0;
  for (int dy = 0; dy < 2; ++dy) {
    for (int dx = 0; dx < 2; ++dx) {
      const float d = in[(2 * y + dy) * in_width + 2 * x + dx];
      if (!valid_depth(d)) continue;
      int i = n++;
      while (i > 0 && samples[i - 1] > d) {
        samples[i] = samples[i - 1];
        --i;
      }
      samples[i] = d;
    }
  }
  if (n == 0) return 0.0f;
  const float median = samples[(n - 1) / 2];
  float sum = 0.0f;
  int count = 0;
  for (int i = 0; i < n; ++i) {
    if (std::fabs(samples[i] - median) <= band_m) {
      sum += samples[i];
      ++count;
    }
  }
  return sum / static_cast<float>(count);
}

Eigen::Vector3f reference_normal(const std::vector<float>& depth,
                                 const std::vector<Eigen::Vector3f>& vertices, int w, int h, int x,
                                 int y, float jump_m) {
  if (x == 0 || y == 0 || x == w - 1 || y == h - 1) return Eigen::Vector3f::Zero();
  const float d = depth[y * w + x];
  const float around[4] = {depth[y * w + x - 1], depth[y * w + x + 1], depth[(y - 1) * w + x],
                           depth[(y + 1) * w + x]};
  if (!valid_depth(d)) return Eigen::Vector3f::Zero();
  for (const float a : around) {
    if (!valid_depth(a) || std::fabs(a - d) > jump_m) return Eigen::Vector3f::Zero();
  }
  const Eigen::Vector3f dx = vertices[y * w + x + 1] - vertices[y * w + x - 1];
  const Eigen::Vector3f dy = vertices[(y + 1) * w + x] - vertices[(y - 1) * w + x];
  const Eigen::Vector3f n = dy.cross(dx);
  const float norm = n.norm();
  return norm > 0.0f && std::isfinite(norm) ? Eigen::Vector3f(n / norm) : Eigen::Vector3f::Zero();
}

TEST_CASE("down-sampling and normals give the bits of the per-pixel code") {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  // Widths around the filters' 64-pixel chunks; depth steps, holes, NaN, infinities, negatives.
  for (const int out_width : {1, 3, 63, 64, 65, 131}) {
    CAPTURE(out_width);
    const int out_height = 9;
    const int in_width = 2 * out_width + 1;  // one column more than the blocks use
    const int in_height = 2 * out_height;
    std::mt19937 rng(static_cast<unsigned>(out_width));
    std::uniform_real_distribution<float> noise_m(-0.01f, 0.01f);
    std::uniform_int_distribution<int> kind(0, 99);
    std::vector<float> in(static_cast<std::size_t>(in_width * in_height));
    for (int y = 0; y < in_height; ++y) {
      for (int x = 0; x < in_width; ++x) {
        float& d = in[static_cast<std::size_t>(y * in_width + x)];
        switch (kind(rng)) {
          case 0:
            d = 0.0f;
            break;
          case 1:
            d = nan;
            break;
          case 2:
            d = inf;
            break;
          case 3:
            d = -1.0f;
            break;
          // Steps of 0.5 m every 40 columns, at an odd column: some blocks straddle them.
          default:
            d = 1.0f + 0.5f * static_cast<float>((x + 1) / 40) + noise_m(rng);
            break;
        }
      }
    }
    const WorkerTeam team(1);
    std::vector<float> half(static_cast<std::size_t>(out_width * out_height), -7.0f);
    REQUIRE(downsample_depth(view(in, in_width, in_height),
                             ImageView<float>(half.data(), out_width, out_height), 2, 0.1f, team)
                .ok());
    for (int y = 0; y < out_height; ++y) {
      for (int x = 0; x < out_width; ++x) {
        const float expected = reference_downsample_pixel(in, in_width, x, y, 0.1f);
        const float got = half[static_cast<std::size_t>(y * out_width + x)];
        CHECK(std::memcmp(&expected, &got, sizeof(float)) == 0);
      }
    }
    const PinholeCamera camera = small_camera(out_width, out_height);
    std::vector<Eigen::Vector3f> vertices(half.size());
    std::vector<Eigen::Vector3f> normals(half.size(), Eigen::Vector3f::Constant(-7.0f));
    REQUIRE(depth_to_vertices(view(half, out_width, out_height), camera,
                              ImageView<Eigen::Vector3f>(vertices.data(), out_width, out_height),
                              team)
                .ok());
    REQUIRE(vertices_to_normals(
                view(half, out_width, out_height),
                ImageView<const Eigen::Vector3f>(vertices.data(), out_width, out_height), 0.05f,
                ImageView<Eigen::Vector3f>(normals.data(), out_width, out_height), team)
                .ok());
    int normals_valid = 0;
    for (int y = 0; y < out_height; ++y) {
      for (int x = 0; x < out_width; ++x) {
        const Eigen::Vector3f expected =
            reference_normal(half, vertices, out_width, out_height, x, y, 0.05f);
        const Eigen::Vector3f& got = normals[static_cast<std::size_t>(y * out_width + x)];
        CAPTURE(x, y);
        CHECK(std::memcmp(expected.data(), got.data(), sizeof(Eigen::Vector3f)) == 0);
        if (!expected.isZero()) ++normals_valid;
      }
    }
    if (out_width >= 63) CHECK(normals_valid > out_width);  // the comparison covered real normals
  }
}

}  // namespace
}  // namespace octofuse
