#include "octofuse/fusion/fusion_config.hpp"

#include <cmath>

#include <catch2/catch.hpp>

namespace octofuse {
namespace {

TEST_CASE("scale from the footprint ratio at the thresholds", "[fusion][scale]") {
  CHECK(scale_for_ratio(0.0f) == 0);
  CHECK(scale_for_ratio(1.4999f) == 0);
  CHECK(scale_for_ratio(1.5f) == 1);
  CHECK(scale_for_ratio(2.9999f) == 1);
  CHECK(scale_for_ratio(3.0f) == 2);
  CHECK(scale_for_ratio(5.9999f) == 2);
  CHECK(scale_for_ratio(6.0f) == 3);
  CHECK(scale_for_ratio(100.0f) == 3);
}

TEST_CASE("scale selection: hysteresis, one refinement step, immediate coarsening",
          "[fusion][scale]") {
  constexpr float kHysteresis = 0.1f;
  // A block never integrated takes the raw scale.
  CHECK(select_scale(5.0f, -1, kHysteresis) == 2);
  // Just past a threshold but inside the margin: no change either way.
  CHECK(select_scale(1.6f, 0, kHysteresis) == 0);  // 1.6 / 1.1 < 1.5
  CHECK(select_scale(1.4f, 1, kHysteresis) == 1);  // 1.4 * 1.1 >= 1.5
  // Beyond the margin: changes.
  CHECK(select_scale(1.7f, 0, kHysteresis) == 1);  // 1.7 / 1.1 > 1.5
  CHECK(select_scale(1.3f, 1, kHysteresis) == 0);  // 1.3 * 1.1 < 1.5
  // Refinement: one step per frame even when the ratio asks for more.
  CHECK(select_scale(0.5f, 3, kHysteresis) == 2);
  CHECK(select_scale(0.5f, 2, kHysteresis) == 1);
  // Coarsening may jump.
  CHECK(select_scale(10.0f, 0, kHysteresis) == 3);
  // No hysteresis: exact thresholds.
  CHECK(select_scale(1.5f, 0, 0.0f) == 1);
  CHECK(select_scale(1.4999f, 1, 0.0f) == 0);
}

TEST_CASE("fusion config validation", "[fusion][config]") {
  FusionConfig c;
  CHECK(validate(c).ok());
  c.mu_m = 0.0f;
  CHECK(validate(c) == StatusCode::invalid_argument);
  c = FusionConfig();
  c.near_m = 5.0f;
  CHECK(validate(c) == StatusCode::invalid_argument);
  c = FusionConfig();
  c.fixed_scale = 4;
  CHECK(validate(c) == StatusCode::invalid_argument);
  c = FusionConfig();
  c.max_blocks_per_frame = 0;
  CHECK(validate(c) == StatusCode::invalid_argument);
  c = FusionConfig();
  c.scale_hysteresis = 1.0f;
  CHECK(validate(c) == StatusCode::invalid_argument);
  for (float behind : {0.0f, -0.5f, 1.01f, std::nanf("")}) {
    c = FusionConfig();
    c.behind_mu = behind;
    CHECK(validate(c) == StatusCode::invalid_argument);
  }
  c.behind_mu = 0.25f;
  CHECK(validate(c).ok());
}

TEST_CASE("scale_for_any_current gives the coarsest scale just past the last threshold's margin",
          "[fusion][scale]") {
  for (float hysteresis : {0.0f, 0.1f, 0.5f}) {
    // Just past the threshold by the margin, in float.
    const float edge = 6.0f * (1.0f + hysteresis);
    int coarsest = 0;
    for (float r : {std::nextafter(edge, 0.0f), edge, std::nextafter(edge, 20.0f)}) {
      if (scale_for_any_current(r, hysteresis) != 3) continue;
      ++coarsest;
      for (int current = -1; current <= 3; ++current) {
        REQUIRE(select_scale(r, current, hysteresis) == 3);
      }
    }
    CHECK(coarsest >= 1);
  }
  CHECK(scale_for_any_current(5.9f, 0.0f) != 3);
  CHECK(scale_for_any_current(6.5f, 0.1f) == -1);  // 6.5 / 1.1 < 6: a scale-2 block stays
  CHECK(scale_for_any_current(6.7f, 0.1f) == 3);
}

TEST_CASE("scale_for_any_current is select_scale exactly when no current scale changes it",
          "[fusion][scale]") {
  int independent[4] = {0, 0, 0, 0};
  for (float hysteresis : {0.0f, 0.1f, 0.5f}) {
    for (float r = 0.0f; r < 12.0f; r = std::nextafter(r, 13.0f) + 0.0009f) {
      const int any = scale_for_any_current(r, hysteresis);
      const int first = select_scale(r, -1, hysteresis);
      bool same = true;
      for (int current = 0; current <= 3; ++current) {
        same = same && select_scale(r, current, hysteresis) == first;
      }
      REQUIRE(same == (any >= 0));
      if (any >= 0) {
        REQUIRE(any == first);
        ++independent[any];
      }
    }
  }
  CHECK(independent[0] == 0);  // a block at scale 3 refines one step at a time
  CHECK(independent[1] == 0);
  CHECK(independent[2] > 1000);
  CHECK(independent[3] > 1000);
  CHECK(scale_for_any_current(4.0f, 0.1f) == 2);
  CHECK(scale_for_any_current(3.2f, 0.1f) == -1);  // 3.2 / 1.1 < 3: a scale-1 block stays
  CHECK(scale_for_any_current(5.5f, 0.1f) == -1);  // 5.5 * 1.1 > 6: a scale-3 block stays
  CHECK(scale_for_any_current(6.7f, 0.1f) == 3);
  CHECK(scale_for_any_current(2.0f, 0.1f) == -1);
}

}  // namespace
}  // namespace octofuse
