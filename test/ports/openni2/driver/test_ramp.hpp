#pragma once
// What the test-only OpenNI2 driver serves, shared with the tests that check it: a depth ramp
// (a tilted plane in image space) that moves 1 mm further away every frame, exact in any mode.

namespace octofuse::test::oni {

inline constexpr const char* kUri = "octofuse-test://ramp";
inline constexpr const char* kUriPrefix = "octofuse-test://";
inline constexpr float kHorizontalFov_rad = 1.0225f;  // about a PrimeSense sensor's 58.6 degrees
inline constexpr float kVerticalFov_rad = 0.7954f;
inline constexpr int kFirstFrameIndex = 1;
inline constexpr long long kFirstTimestamp_us = 1000;

// Millimetres at pixel (u, v) of the frame with OpenNI2 frame index `index`.
inline int ramp_depth_mm(int u, int v, int index) {
  return 800 + 2 * u + v + index;
}

// Device timestamp of frame `index` at `fps`.
inline long long ramp_timestamp_us(int index, int fps) {
  return kFirstTimestamp_us + static_cast<long long>(index - kFirstFrameIndex) * 1000000LL / fps;
}

}  // namespace octofuse::test::oni
