#include "octofuse/sensor/frame_validator.hpp"

#include <algorithm>
#include <catch2/catch.hpp>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "support/alloc_counter.hpp"

namespace octofuse {
namespace {

constexpr int kWidth = 8;
constexpr int kHeight = 6;
constexpr float kMetresPerMm = 0.001f;
constexpr float kTolerance_m = 1e-6f;

PinholeCamera small_camera() {
  return PinholeCamera{10.0f, 10.0f, 3.5f, 2.5f, kWidth, kHeight};
}

struct Fixture {
  std::vector<std::uint16_t> raw = std::vector<std::uint16_t>(kWidth * kHeight, 1000);
  std::vector<float> metres = std::vector<float>(kWidth * kHeight, -1.0f);
  FrameValidator validator;
  DepthFrame frame;

  explicit Fixture(FrameValidatorConfig config = FrameValidatorConfig()) {
    REQUIRE(validator.init(small_camera(), config).ok());
    frame.depth_raw = ImageView<const std::uint16_t>(raw.data(), kWidth, kHeight);
    frame.metres_per_unit = kMetresPerMm;
    frame.timestamp_us = 1000;
    frame.sequence = 7;
  }
  ImageView<float> out() { return ImageView<float>(metres.data(), kWidth, kHeight); }
  Status run(FrameReport* report = nullptr) { return validator.validate(frame, out(), report); }
  // Advances time and sequence by one frame.
  void advance() {
    frame.timestamp_us += 33333;
    frame.sequence += 1;
  }
};

TEST_CASE("init rejects a bad camera and bad ranges") {
  FrameValidator v;
  PinholeCamera bad = small_camera();
  bad.fx = 0.0f;
  REQUIRE(v.init(bad, {}).code() == StatusCode::invalid_argument);
  REQUIRE(!std::string(v.last_error()).empty());

  FrameValidatorConfig c;
  c.near_m = 2.0f;
  c.far_m = 1.0f;
  REQUIRE(v.init(small_camera(), c).code() == StatusCode::invalid_argument);
  c = FrameValidatorConfig();
  c.far_m = std::numeric_limits<float>::quiet_NaN();
  REQUIRE(v.init(small_camera(), c).code() == StatusCode::invalid_argument);
  c = FrameValidatorConfig();
  c.min_valid_fraction = 1.5f;
  REQUIRE(v.init(small_camera(), c).code() == StatusCode::invalid_argument);
  c = FrameValidatorConfig();
  c.rigid_tolerance = 0.0;
  REQUIRE(v.init(small_camera(), c).code() == StatusCode::invalid_argument);
}

TEST_CASE("validate before init is a precondition failure") {
  FrameValidator v;
  std::vector<float> metres(kWidth * kHeight);
  DepthFrame frame;
  REQUIRE(v.validate(frame, ImageView<float>(metres.data(), kWidth, kHeight), nullptr).code() ==
          StatusCode::failed_precondition);
}

TEST_CASE("a good frame converts to metres and counts every pixel class") {
  Fixture f;
  f.raw[0] = 0;                   // no measurement
  f.raw[1] = kSaturatedDepthRaw;  // saturated
  f.raw[2] = 399;                 // below near 0.4 m
  f.raw[3] = 4001;                // beyond far 4 m
  f.raw[4] = 400;                 // exactly near: valid
  f.raw[5] = 4000;                // exactly far: valid
  f.raw[6] = 1234;
  FrameReport report;
  REQUIRE(f.run(&report).ok());
  REQUIRE(report.pixel_count == kWidth * kHeight);
  REQUIRE(report.zero_pixels == 1);
  REQUIRE(report.saturated_pixels == 1);
  REQUIRE(report.out_of_range_pixels == 2);
  REQUIRE(report.valid_pixels == kWidth * kHeight - 4);
  REQUIRE(!report.nearly_empty);
  REQUIRE(report.dropped_before == 0);
  for (int i = 0; i < 4; ++i) REQUIRE(f.metres[i] == 0.0f);
  REQUIRE(f.metres[4] == Approx(0.4f).margin(kTolerance_m));
  REQUIRE(f.metres[5] == Approx(4.0f).margin(kTolerance_m));
  REQUIRE(f.metres[6] == Approx(1.234f).margin(kTolerance_m));
  REQUIRE(f.metres[7] == Approx(1.0f).margin(kTolerance_m));
  REQUIRE(f.validator.frames_accepted() == 1);
}

TEST_CASE("every raw value converts and classifies as value * metres_per_unit against near/far") {
  // All 65536 raw values in one 256 x 256 frame, against the per-pixel definition in floats, for
  // scales and limits whose boundaries fall between, on and far outside the raw values.
  constexpr int kSide = 256;
  struct Case {
    float metres_per_unit;
    float near_m;
    float far_m;
  };
  const Case cases[] = {
      {0.001f, 0.4f, 4.0f},       {0.0002f, 0.1f, 8.0f}, {0.00025f, 0.3f, 0.30025f},
      {1.0f / 3.0f, 0.0f, 1e30f}, {1e-3f, 70.0f, 80.0f}, {1e-30f, 0.0f, 1e-40f},
      {3e38f, 1.0f, 2e38f},       {0.1f, 0.0f, 0.05f},   {7.3e-5f, 0.45f, 4.55f},
  };
  const PinholeCamera camera{100.0f, 100.0f, 127.5f, 127.5f, kSide, kSide};
  std::vector<std::uint16_t> raw(kSide * kSide);
  for (std::size_t i = 0; i < raw.size(); ++i) raw[i] = static_cast<std::uint16_t>(i);
  std::vector<float> metres(raw.size());
  std::vector<std::uint8_t> beyond(raw.size());
  for (const Case& c : cases) {
    FrameValidatorConfig config;
    config.near_m = c.near_m;
    config.far_m = c.far_m;
    config.min_valid_fraction = 0.0f;
    FrameValidator validator;
    REQUIRE(validator.init(camera, config).ok());
    DepthFrame frame;
    frame.depth_raw = ImageView<const std::uint16_t>(raw.data(), kSide, kSide);
    frame.metres_per_unit = c.metres_per_unit;
    frame.timestamp_us = 1;
    frame.sequence = 1;
    FrameReport report;
    REQUIRE(validator
                .validate(frame, ImageView<float>(metres.data(), kSide, kSide), &report,
                          ImageView<std::uint8_t>(beyond.data(), kSide, kSide))
                .ok());
    std::uint32_t valid = 0;
    std::uint32_t beyond_far = 0;
    std::size_t mismatches = 0;
    for (std::size_t i = 0; i < raw.size(); ++i) {
      const bool measured = raw[i] != 0 && raw[i] != kSaturatedDepthRaw;
      const float d = static_cast<float>(raw[i]) * c.metres_per_unit;
      const bool in_range = measured && d >= c.near_m && d <= c.far_m;
      const bool is_beyond = measured && d > c.far_m;
      valid += in_range ? 1u : 0u;
      beyond_far += is_beyond ? 1u : 0u;
      const float expected = in_range ? d : 0.0f;
      if (std::memcmp(&metres[i], &expected, sizeof(float)) != 0 ||
          beyond[i] != (is_beyond ? 1 : 0)) {
        ++mismatches;
      }
    }
    INFO("metres_per_unit " << c.metres_per_unit << " near " << c.near_m << " far " << c.far_m);
    REQUIRE(mismatches == 0);
    REQUIRE(report.zero_pixels == 1);
    REQUIRE(report.saturated_pixels == 1);
    REQUIRE(report.valid_pixels == valid);
    REQUIRE(report.beyond_far_pixels == beyond_far);
    REQUIRE(report.out_of_range_pixels == kSide * kSide - 2 - valid);
  }
}

TEST_CASE("pixels measured beyond far are marked for free space; no return and too near are not") {
  Fixture f;
  f.raw[0] = 0;                   // no measurement
  f.raw[1] = kSaturatedDepthRaw;  // saturated: not a measurement either
  f.raw[2] = 399;                 // below near
  f.raw[3] = 4001;                // beyond far
  f.raw[4] = 4000;                // exactly far: valid depth
  f.raw[5] = 9000;                // beyond far
  std::vector<std::uint8_t> beyond(kWidth * kHeight, 7);
  FrameReport report;
  REQUIRE(f.validator
              .validate(f.frame, f.out(), &report,
                        ImageView<std::uint8_t>(beyond.data(), kWidth, kHeight))
              .ok());
  REQUIRE(report.out_of_range_pixels == 3);
  REQUIRE(report.beyond_far_pixels == 2);
  const std::uint8_t expected[6] = {0, 0, 0, 1, 0, 1};
  for (int i = 0; i < 6; ++i) REQUIRE(beyond[static_cast<std::size_t>(i)] == expected[i]);
  for (std::size_t i = 6; i < beyond.size(); ++i) REQUIRE(beyond[i] == 0);
  REQUIRE(f.metres[3] == 0.0f);
  REQUIRE(f.metres[5] == 0.0f);

  // Without a mask the counts are the same; a mask of the wrong size is a caller error.
  f.advance();
  FrameReport plain;
  REQUIRE(f.run(&plain).ok());
  REQUIRE(plain.beyond_far_pixels == 2);
  f.advance();
  REQUIRE(f.validator
              .validate(f.frame, f.out(), nullptr,
                        ImageView<std::uint8_t>(beyond.data(), kWidth - 1, kHeight))
              .code() == StatusCode::failed_precondition);
}

TEST_CASE("metres_per_unit scales raw depth (TUM 5000 units per metre)") {
  Fixture f;
  f.frame.metres_per_unit = 0.0002f;
  f.raw[0] = 5000;
  REQUIRE(f.run().ok());
  REQUIRE(f.metres[0] == Approx(1.0f).margin(kTolerance_m));
  REQUIRE(f.metres[1] == 0.0f);  // 1000 units = 0.2 m, below near
}

TEST_CASE("the near/far limits come from the config") {
  FrameValidatorConfig c;
  c.near_m = 0.1f;
  c.far_m = 0.5f;
  Fixture f(c);
  f.raw[0] = 200;
  FrameReport report;
  REQUIRE(f.run(&report).ok());
  REQUIRE(report.valid_pixels == 1);
  REQUIRE(report.out_of_range_pixels == kWidth * kHeight - 1);
  REQUIRE(f.metres[0] == Approx(0.2f).margin(kTolerance_m));
}

TEST_CASE("output stride is honoured") {
  Fixture f;
  std::vector<float> wide(static_cast<std::size_t>(kWidth + 3) * kHeight, -7.0f);
  REQUIRE(
      f.validator
          .validate(f.frame, ImageView<float>(wide.data(), kWidth, kHeight, kWidth + 3), nullptr)
          .ok());
  REQUIRE(wide[kWidth] == -7.0f);  // padding untouched
  REQUIRE(wide[kWidth + 3] == Approx(1.0f).margin(kTolerance_m));
}

TEST_CASE("wrong sizes are invalid_argument and leave the output alone") {
  Fixture f;
  SECTION("width") {
    f.frame.depth_raw = ImageView<const std::uint16_t>(f.raw.data(), kWidth - 1, kHeight);
  }
  SECTION("height") {
    f.frame.depth_raw = ImageView<const std::uint16_t>(f.raw.data(), kWidth, kHeight - 1);
  }
  SECTION("null pixels") {
    f.frame.depth_raw = ImageView<const std::uint16_t>(nullptr, kWidth, kHeight);
  }
  SECTION("stride below width") {
    f.frame.depth_raw = ImageView<const std::uint16_t>(f.raw.data(), kWidth, kHeight);
    f.frame.depth_raw.stride = kWidth - 1;
  }
  REQUIRE(f.run().code() == StatusCode::invalid_argument);
  REQUIRE(std::strstr(f.validator.last_error(), "expected 8x6") != nullptr);
  REQUIRE(f.metres[0] == -1.0f);
  REQUIRE(f.validator.frames_rejected() == 1);
}

TEST_CASE("an output buffer of the wrong size is a caller error") {
  Fixture f;
  REQUIRE(
      f.validator.validate(f.frame, ImageView<float>(f.metres.data(), kWidth, kHeight - 1), nullptr)
          .code() == StatusCode::failed_precondition);
}

TEST_CASE("metres_per_unit must be finite and positive") {
  Fixture f;
  for (float bad : {0.0f, -0.001f, std::numeric_limits<float>::quiet_NaN(),
                    std::numeric_limits<float>::infinity()}) {
    f.frame.metres_per_unit = bad;
    REQUIRE(f.run().code() == StatusCode::invalid_argument);
  }
}

TEST_CASE("timestamps must strictly increase") {
  Fixture f;
  REQUIRE(f.run().ok());
  f.frame.sequence += 1;  // same timestamp
  REQUIRE(f.run().code() == StatusCode::invalid_argument);
  REQUIRE(std::strstr(f.validator.last_error(), "timestamp") != nullptr);
  f.frame.timestamp_us -= 10;  // going back
  REQUIRE(f.run().code() == StatusCode::invalid_argument);
  // The rejected frames did not move the reference: the next proper frame is fine.
  f.frame.timestamp_us += 20;
  REQUIRE(f.run().ok());
  REQUIRE(f.validator.frames_accepted() == 2);
  REQUIRE(f.validator.frames_rejected() == 2);
}

TEST_CASE("restart_stream forgets the previous time") {
  Fixture f;
  REQUIRE(f.run().ok());
  f.validator.restart_stream();
  f.frame.timestamp_us = 0;
  f.frame.sequence = 0;
  REQUIRE(f.run().ok());
}

TEST_CASE("sequence gaps count as dropped frames, repeats are rejected") {
  Fixture f;
  FrameReport report;
  REQUIRE(f.run(&report).ok());
  f.advance();
  REQUIRE(f.run(&report).ok());
  REQUIRE(report.dropped_before == 0);
  f.advance();
  f.frame.sequence += 3;  // three frames lost
  REQUIRE(f.run(&report).ok());
  REQUIRE(report.dropped_before == 3);
  f.advance();
  f.frame.sequence += 1;
  REQUIRE(f.run(&report).ok());
  REQUIRE(report.dropped_before == 1);
  REQUIRE(f.validator.frames_dropped() == 4);

  f.frame.timestamp_us += 33333;  // sequence unchanged: a repeat
  REQUIRE(f.run(&report).code() == StatusCode::invalid_argument);
  REQUIRE(std::strstr(f.validator.last_error(), "sequence") != nullptr);
}

TEST_CASE("ground truth must be finite and rigid") {
  Fixture f;
  f.frame.has_ground_truth = true;
  Se3d T = Se3d::Identity();
  T.rotate(Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()));
  T.translation() = Eigen::Vector3d(1, -2, 0.5);
  f.frame.T_W_C_ground_truth = T.matrix();
  REQUIRE(f.run().ok());

  SECTION("non-finite") {
    f.advance();
    f.frame.T_W_C_ground_truth(0, 3) = std::numeric_limits<double>::quiet_NaN();
    REQUIRE(f.run().code() == StatusCode::invalid_argument);
    REQUIRE(std::strstr(f.validator.last_error(), "non-finite") != nullptr);
  }
  SECTION("scaled rotation") {
    f.advance();
    f.frame.T_W_C_ground_truth.topLeftCorner<3, 3>() *= 1.01;
    REQUIRE(f.run().code() == StatusCode::invalid_argument);
    REQUIRE(std::strstr(f.validator.last_error(), "rigid") != nullptr);
  }
  SECTION("reflection") {
    f.advance();
    f.frame.T_W_C_ground_truth.col(0) *= -1.0;
    REQUIRE(f.run().code() == StatusCode::invalid_argument);
  }
  SECTION("bad bottom row") {
    f.advance();
    f.frame.T_W_C_ground_truth(3, 0) = 0.5;
    REQUIRE(f.run().code() == StatusCode::invalid_argument);
  }
  SECTION("ignored when the frame has none") {
    f.advance();
    f.frame.has_ground_truth = false;
    f.frame.T_W_C_ground_truth(0, 0) = std::numeric_limits<double>::quiet_NaN();
    REQUIRE(f.run().ok());
  }
}

TEST_CASE("a frame with almost no valid pixels is reported as nearly empty") {
  Fixture f;
  std::fill(f.raw.begin(), f.raw.end(), std::uint16_t{0});
  FrameReport report;
  REQUIRE(f.run(&report).code() == StatusCode::data_loss);
  REQUIRE(report.nearly_empty);
  REQUIRE(report.zero_pixels == kWidth * kHeight);
  REQUIRE(std::strstr(f.validator.last_error(), "only 0 of 48") != nullptr);
  // It still counts as accepted (time moves on), and the output holds zeros.
  REQUIRE(f.validator.frames_accepted() == 1);
  for (float m : f.metres) REQUIRE(m == 0.0f);

  // One valid pixel in 48 is above a 1 % threshold.
  f.advance();
  f.raw[10] = 1500;
  REQUIRE(f.run(&report).ok());
  REQUIRE(report.valid_pixels == 1);
  REQUIRE(report.valid_fraction() == Approx(1.0f / 48.0f));
}

TEST_CASE("validate allocates nothing") {
  Fixture f;
  f.frame.has_ground_truth = true;
  FrameReport report;
  int good = 0;
  test::AllocationScope scope;
  for (int i = 0; i < 100; ++i) {
    if (f.run(&report).ok()) ++good;
    f.advance();
  }
  f.frame.metres_per_unit = -1.0f;
  const Status bad = f.run(&report);
  const std::uint64_t allocations = scope.allocations();
  REQUIRE(good == 100);
  REQUIRE(bad.code() == StatusCode::invalid_argument);
  REQUIRE(allocations == 0);
}

}  // namespace
}  // namespace octofuse
