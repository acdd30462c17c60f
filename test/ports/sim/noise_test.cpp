#include "octofuse/ports/sim/noise.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <cstdint>
#include <vector>

#include "octofuse/ports/sim/random.hpp"

namespace octofuse::sim {
namespace {

constexpr int kWidth = 640;
constexpr int kHeight = 480;
constexpr float kFx = 525.0f;
constexpr float kMetresPerUnit = 0.001f;
constexpr float kMinRange_m = 0.2f;
constexpr float kMaxRange_m = 6.0f;
constexpr double kSigmaTolerance = 0.2;  // sample std within 20 % of the model
constexpr double kTolerance_m = 1e-9;

struct Images {
  std::vector<float> depth = std::vector<float>(kWidth * kHeight, 0.0f);
  std::vector<float> cosine = std::vector<float>(kWidth * kHeight, 1.0f);
  std::vector<std::uint16_t> raw = std::vector<std::uint16_t>(kWidth * kHeight, 0);

  void fill(float z) { depth.assign(depth.size(), z); }
  void apply(const KinectNoiseModel& model, std::uint64_t seed = 1, std::uint64_t frame = 0) {
    apply_kinect_noise(model, kFx, ImageView<const float>(depth.data(), kWidth, kHeight),
                       ImageView<const float>(cosine.data(), kWidth, kHeight), kMetresPerUnit,
                       kMinRange_m, kMaxRange_m, seed, frame,
                       ImageView<std::uint16_t>(raw.data(), kWidth, kHeight));
  }
  // Sample mean and standard deviation (metres) of the valid pixels.
  void stats(double* mean, double* stddev, int* valid) const {
    double sum = 0.0;
    double sum2 = 0.0;
    int n = 0;
    for (std::uint16_t v : raw) {
      if (v == 0) continue;
      const double z = v * static_cast<double>(kMetresPerUnit);
      sum += z;
      sum2 += z * z;
      ++n;
    }
    *valid = n;
    *mean = sum / n;
    *stddev = std::sqrt(std::max(0.0, sum2 / n - *mean * *mean));
  }
};

TEST_CASE("the axial model is 1.2 mm at 0.4 m and grows with the square of the distance") {
  KinectNoiseModel m;
  REQUIRE(m.axial_sigma_m(0.4) == Approx(0.0012).margin(kTolerance_m));
  REQUIRE(m.axial_sigma_m(1.4) == Approx(0.0012 + 0.0019).margin(kTolerance_m));
  REQUIRE(m.axial_sigma_m(3.4) == Approx(0.0012 + 0.0019 * 9.0).margin(kTolerance_m));
  // One disparity step (1/8 px, 7.5 cm baseline, fx 525) is z^2 / 315 m.
  REQUIRE(m.disparity_depth_step_m(1.0, kFx) == Approx(1.0 / 315.0).margin(kTolerance_m));
  // The gaussian part leaves room for the quantisation variance.
  const double step = m.disparity_depth_step_m(2.0, kFx);
  REQUIRE(m.gaussian_sigma_m(2.0, kFx) * m.gaussian_sigma_m(2.0, kFx) + step * step / 12.0 ==
          Approx(m.axial_sigma_m(2.0) * m.axial_sigma_m(2.0)).margin(kTolerance_m));
}

TEST_CASE("sample standard deviation on a plane matches sigma(z)") {
  KinectNoiseModel model;
  model.edge_dropout_probability = 0.0;  // a flat frontal plane has no edges anyway
  for (const bool quantise : {false, true}) {
    model.disparity_quantisation = quantise;
    for (const float z : {0.6f, 1.0f, 2.0f, 3.0f}) {
      Images img;
      img.fill(z);
      img.apply(model);
      double mean = 0.0;
      double stddev = 0.0;
      int valid = 0;
      img.stats(&mean, &stddev, &valid);
      INFO("z " << z << " quantised " << quantise);
      REQUIRE(valid == kWidth * kHeight);
      const double sigma = model.axial_sigma_m(z);
      REQUIRE(stddev == Approx(sigma).epsilon(kSigmaTolerance));
      REQUIRE(std::abs(mean - z) < 0.2 * sigma);  // unbiased
    }
  }
}

TEST_CASE("quantised depth lies on the disparity grid") {
  KinectNoiseModel model;
  Images img;
  img.fill(2.5f);
  img.apply(model);
  const double fb = kFx * model.baseline_m;
  for (std::uint16_t v : img.raw) {
    REQUIRE(v != 0);
    const double z = v * static_cast<double>(kMetresPerUnit);
    const double k = std::round(fb / z / model.disparity_step_px);
    // Only millimetre rounding separates the value from a grid depth.
    REQUIRE(std::abs(fb / (k * model.disparity_step_px) - z) <= 0.0005 + 1e-9);
  }
}

TEST_CASE("noise is deterministic for a seed and frame, and differs otherwise") {
  KinectNoiseModel model;
  Images a;
  Images b;
  a.fill(1.7f);
  b.fill(1.7f);
  a.apply(model, 7, 3);
  b.apply(model, 7, 3);
  REQUIRE(a.raw == b.raw);
  b.apply(model, 8, 3);
  REQUIRE(a.raw != b.raw);
  b.apply(model, 7, 4);
  REQUIRE(a.raw != b.raw);
}

TEST_CASE("noise off rounds exact depth to units and applies only the sensor range") {
  KinectNoiseModel model;
  model.enabled = false;
  Images img;
  img.depth[0] = 0.1f;  // below min range
  img.depth[1] = 6.5f;  // beyond max range
  img.depth[2] = 1.2344f;
  img.depth[3] = 0.0f;   // no surface
  img.cosine[4] = 0.0f;  // grazing: ignored without noise
  img.depth[4] = 2.0f;
  img.apply(model);
  REQUIRE(img.raw[0] == 0);
  REQUIRE(img.raw[1] == 0);
  REQUIRE(img.raw[2] == 1234);
  REQUIRE(img.raw[3] == 0);
  REQUIRE(img.raw[4] == 2000);
}

TEST_CASE("grazing angles drop out") {
  KinectNoiseModel model;
  Images img;
  img.fill(1.5f);
  const double deg = 3.14159265358979323846 / 180.0;
  const int half = kWidth * kHeight / 2;
  for (int i = 0; i < half; ++i) img.cosine[i] = static_cast<float>(std::cos(88.0 * deg));
  for (int i = half; i < kWidth * kHeight; ++i) {
    img.cosine[i] = static_cast<float>(std::cos(60.0 * deg));
  }
  img.apply(model);
  for (int i = 0; i < half; ++i) REQUIRE(img.raw[i] == 0);
  for (int i = half; i < kWidth * kHeight; ++i) REQUIRE(img.raw[i] != 0);

  // Half way through the ramp, about half survive.
  const double mid =
      0.5 * (std::cos(model.grazing_start_deg * deg) + std::cos(model.grazing_full_deg * deg));
  img.cosine.assign(img.cosine.size(), static_cast<float>(mid));
  img.apply(model);
  int kept = 0;
  for (std::uint16_t v : img.raw) kept += v != 0;
  REQUIRE(kept == Approx(0.5 * kWidth * kHeight).epsilon(0.05));
}

TEST_CASE("pixels just behind a depth edge drop out, those in front never") {
  KinectNoiseModel model;
  Images img;
  // Left half at 1 m, right half at 2 m: column 320 is behind the edge.
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) img.depth[y * kWidth + x] = x < kWidth / 2 ? 1.0f : 2.0f;
  }
  img.apply(model);
  int dropped_behind = 0;
  for (int y = 0; y < kHeight; ++y) {
    REQUIRE(img.raw[y * kWidth + kWidth / 2 - 1] != 0);  // the near side keeps its pixels
    dropped_behind += img.raw[y * kWidth + kWidth / 2] == 0;
    REQUIRE(img.raw[y * kWidth + kWidth / 2 + 1] != 0);  // one pixel further is not an edge
  }
  REQUIRE(dropped_behind == Approx(model.edge_dropout_probability * kHeight).epsilon(0.25));
}

TEST_CASE("the gaussian draw has unit variance and bounded tails") {
  double sum = 0.0;
  double sum2 = 0.0;
  constexpr int kSamples = 200000;
  for (int i = 0; i < kSamples; ++i) {
    const double g = gaussian_from_bits(hash_key(1, static_cast<std::uint64_t>(i), 2, 3));
    REQUIRE(std::abs(g) <= std::sqrt(12.0));
    sum += g;
    sum2 += g * g;
  }
  REQUIRE(sum / kSamples == Approx(0.0).margin(0.01));
  REQUIRE(sum2 / kSamples == Approx(1.0).epsilon(0.02));
}

}  // namespace
}  // namespace octofuse::sim
