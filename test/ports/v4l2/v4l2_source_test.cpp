#include "octofuse/ports/v4l2/v4l2_source.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <cstring>
#include <string>

#include "ports/v4l2/fake_v4l2_device.hpp"
#include "support/alloc_counter.hpp"
#include "support/text.hpp"

namespace octofuse {
namespace {

using ports::V4l2DepthFormat;
using ports::V4l2Options;
using ports::V4l2Source;
using test::contains;
using test::FakeV4l2Device;

constexpr float kPixelTolerance_px = 1e-3f;

V4l2Options small_z16() {
  V4l2Options options;
  options.format = V4l2DepthFormat::z16;
  options.width = 64;
  options.height = 48;
  options.buffer_count = 4;
  options.frame_timeout_ms = 200;
  return options;
}

// Pixel (x, y) of the frame with driver sequence `sequence` as the fake's poll() captures it.
std::uint16_t expected_pixel(std::uint64_t sequence, int x, int y) {
  return static_cast<std::uint16_t>(1000 + sequence + static_cast<std::uint64_t>(x + y));
}

bool frame_matches(const DepthFrame& frame, std::uint64_t sequence) {
  for (int y = 0; y < frame.depth_raw.height; ++y) {
    for (int x = 0; x < frame.depth_raw.width; ++x) {
      if (frame.depth_raw(x, y) != expected_pixel(sequence, x, y)) return false;
    }
  }
  return true;
}

TEST_CASE("v4l2: negotiates Z16, maps a ring and delivers frames in driver order") {
  FakeV4l2Device device;
  V4l2Source source(FakeV4l2Device::kPath, small_z16(), device);
  REQUIRE(source.open().ok());
  CHECK(source.pixel_format() == V4L2_PIX_FMT_Z16);
  CHECK(source.buffer_count() == 4);
  CHECK(device.mapped_count() == 4);
  CHECK(device.queued_count() == 4);
  CHECK(device.streaming());

  const SourceCapabilities caps = source.capabilities();
  CHECK(caps.live);
  CHECK_FALSE(caps.has_ground_truth);
  CHECK(caps.ring_size == 2);
  CHECK(caps.nominal_rate_hz == Approx(30.0f));

  // Default intrinsics: 87 degrees horizontal field of view, centred principal point.
  const PinholeCamera camera = source.intrinsics();
  const float expected_f = 32.0f / std::tan(0.5f * 87.0f * 3.14159265f / 180.0f);
  CHECK(camera.width == 64);
  CHECK(camera.height == 48);
  CHECK(camera.fx == Approx(expected_f).margin(kPixelTolerance_px));
  CHECK(camera.fy == Approx(expected_f).margin(kPixelTolerance_px));
  CHECK(camera.cx == Approx(31.5f).margin(kPixelTolerance_px));
  CHECK(camera.cy == Approx(23.5f).margin(kPixelTolerance_px));

  std::int64_t last_timestamp_us = 0;
  for (std::uint64_t k = 0; k < 6; ++k) {
    DepthFrame frame;
    const NextFrame got = source.next(frame);
    REQUIRE(got.outcome == FrameOutcome::frame);
    CHECK(got.status.ok());
    CHECK(frame.sequence == k);
    CHECK(frame.depth_raw.width == 64);
    CHECK(frame.depth_raw.height == 48);
    // The driver pads rows: the view carries its stride in pixels.
    CHECK(frame.depth_raw.stride == static_cast<std::ptrdiff_t>(device.bytes_per_line() / 2));
    CHECK(frame.metres_per_unit == 0.001f);
    CHECK(frame.timestamp_us == 1000000 + static_cast<std::int64_t>(k + 1) * 33333);
    CHECK(frame.timestamp_us > last_timestamp_us);
    last_timestamp_us = frame.timestamp_us;
    CHECK(frame_matches(frame, k));
  }
  source.close();
  CHECK(device.open_count() == 0);
  CHECK(device.mapped_count() == 0);
  CHECK(device.buffer_count() == 0);
  CHECK_FALSE(device.streaming());
  source.close();  // twice is harmless
}

TEST_CASE("v4l2: frames stay valid for ring_size calls; the oldest goes back to the driver") {
  FakeV4l2Device device;
  V4l2Source source(FakeV4l2Device::kPath, small_z16(), device);
  REQUIRE(source.open().ok());
  const int ring = source.capabilities().ring_size;
  REQUIRE(ring == 2);

  DepthFrame frames[3];
  REQUIRE(source.next(frames[0]).outcome == FrameOutcome::frame);
  REQUIRE(source.next(frames[1]).outcome == FrameOutcome::frame);
  // Both held: neither buffer is queued, both views still show their own frame.
  CHECK(device.queued_count() == 2);
  CHECK(frame_matches(frames[0], 0));
  CHECK(frame_matches(frames[1], 1));
  REQUIRE(source.next(frames[2]).outcome == FrameOutcome::frame);
  CHECK(frame_matches(frames[1], 1));
  CHECK(frame_matches(frames[2], 2));
  CHECK(device.queued_count() == 2);  // frame 0's buffer was requeued, then frame 2 dequeued
}

TEST_CASE("v4l2: Y16 with a configured scale; 'any' falls back to Y16") {
  FakeV4l2Device device;
  device.formats = {V4L2_PIX_FMT_YUYV, V4L2_PIX_FMT_Y16};
  V4l2Options options = small_z16();
  options.format = V4l2DepthFormat::any;
  options.metres_per_unit = 0.000125f;
  V4l2Source source(FakeV4l2Device::kPath, options, device);
  REQUIRE(source.open().ok());
  CHECK(source.pixel_format() == V4L2_PIX_FMT_Y16);
  DepthFrame frame;
  REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
  CHECK(frame.metres_per_unit == 0.000125f);
  CHECK(frame_matches(frame, 0));
}

TEST_CASE("v4l2: a device without a 16-bit depth format is refused, naming what it offers") {
  FakeV4l2Device device;
  device.formats = {V4L2_PIX_FMT_YUYV, V4L2_PIX_FMT_MJPEG};
  V4l2Source source(FakeV4l2Device::kPath, small_z16(), device);
  REQUIRE(source.open().code() == StatusCode::invalid_argument);
  CHECK(contains(source.last_error(), "'YUYV', 'MJPG'"));
  CHECK(contains(source.last_error(), "'Z16 '"));
  CHECK(device.open_count() == 0);

  // Asking for Z16 from a Y16-only device names the Y16 it does offer.
  FakeV4l2Device y16_only;
  y16_only.formats = {V4L2_PIX_FMT_Y16};
  V4l2Source z16(FakeV4l2Device::kPath, small_z16(), y16_only);
  REQUIRE(z16.open().code() == StatusCode::invalid_argument);
  CHECK(contains(z16.last_error(), "'Y16 '"));
  CHECK(y16_only.open_count() == 0);
}

TEST_CASE("v4l2: a size the driver adjusts is refused with the size it gives") {
  FakeV4l2Device device;
  V4l2Options options = small_z16();
  options.width = 40;
  options.height = 30;
  V4l2Source source(FakeV4l2Device::kPath, options, device);
  REQUIRE(source.open().code() == StatusCode::invalid_argument);
  CHECK(contains(source.last_error(), "32x24"));
  CHECK(device.open_count() == 0);

  // Without a requested size the device's current size is taken (a format set on a V4L2 device
  // persists: the refused attempt above left it at 32x24).
  options.width = options.height = 0;
  V4l2Source any_size(FakeV4l2Device::kPath, options, device);
  REQUIRE(any_size.open().ok());
  CHECK(any_size.intrinsics().width == 32);
  CHECK(any_size.intrinsics().height == 24);
}

TEST_CASE("v4l2: explicit intrinsics must match the negotiated size") {
  FakeV4l2Device device;
  V4l2Options options = small_z16();
  options.intrinsics = PinholeCamera{50.0f, 51.0f, 30.0f, 20.0f, 64, 48};
  V4l2Source source(FakeV4l2Device::kPath, options, device);
  REQUIRE(source.open().ok());
  CHECK(source.intrinsics().fx == 50.0f);
  CHECK(source.intrinsics().cy == 20.0f);
  source.close();

  options.intrinsics.width = 640;
  V4l2Source mismatched(FakeV4l2Device::kPath, options, device);
  REQUIRE(mismatched.open().code() == StatusCode::invalid_argument);
  CHECK(device.open_count() == 0);
}

TEST_CASE("v4l2: missing device, bad options and wrong state") {
  FakeV4l2Device device;
  V4l2Source missing("/dev/video99", small_z16(), device);
  CHECK(missing.open().code() == StatusCode::unavailable);
  CHECK(contains(missing.last_error(), "/dev/video99"));

  DepthFrame frame;
  const NextFrame early = missing.next(frame);
  CHECK(early.outcome == FrameOutcome::error);
  CHECK(early.status.code() == StatusCode::failed_precondition);

  V4l2Options bad = small_z16();
  bad.buffer_count = 2;
  V4l2Source too_few(FakeV4l2Device::kPath, bad, device);
  CHECK(too_few.open().code() == StatusCode::invalid_argument);
  bad = small_z16();
  bad.metres_per_unit = std::nanf("");
  V4l2Source nan_scale(FakeV4l2Device::kPath, bad, device);
  CHECK(nan_scale.open().code() == StatusCode::invalid_argument);
  bad = small_z16();
  bad.height = 0;
  V4l2Source half_size(FakeV4l2Device::kPath, bad, device);
  CHECK(half_size.open().code() == StatusCode::invalid_argument);
  V4l2Source null_path(nullptr, small_z16(), device);
  CHECK(null_path.open().code() == StatusCode::invalid_argument);
  CHECK(device.open_count() == 0);

  V4l2Source twice(FakeV4l2Device::kPath, small_z16(), device);
  REQUIRE(twice.open().ok());
  CHECK(twice.open().code() == StatusCode::failed_precondition);
}

TEST_CASE("v4l2: a driver that gives too many buffers is refused and cleaned up") {
  FakeV4l2Device device;
  device.min_buffers = 8;  // more than asked is legal for a driver
  V4l2Options options = small_z16();
  options.buffer_count = 3;
  V4l2Source source(FakeV4l2Device::kPath, options, device);
  REQUIRE(source.open().ok());  // 8 is within kMaxBuffers
  CHECK(source.buffer_count() == 8);
  CHECK(source.capabilities().ring_size == 6);
}

TEST_CASE("v4l2: no frame within the timeout gives deadline_exceeded, then frames resume") {
  FakeV4l2Device device;
  device.frames_on_poll = 0;
  V4l2Source source(FakeV4l2Device::kPath, small_z16(), device);
  REQUIRE(source.open().ok());
  const std::int64_t before_us = device.now_us();
  DepthFrame frame;
  const NextFrame timed_out = source.next(frame);
  CHECK(timed_out.outcome == FrameOutcome::skip);
  CHECK(timed_out.status.code() == StatusCode::deadline_exceeded);
  CHECK(device.now_us() - before_us == 200 * 1000);  // waited exactly the timeout, once

  REQUIRE(device.capture(5000));
  const NextFrame got = source.next(frame);
  REQUIRE(got.outcome == FrameOutcome::frame);
  CHECK(frame.depth_raw(3, 2) == 5005);
}

TEST_CASE("v4l2: EINTR and EAGAIN are retried transparently") {
  FakeV4l2Device device;
  device.dqbuf_errors = {EINTR, EINTR, EAGAIN};
  device.poll_errors = {EINTR};
  V4l2Source source(FakeV4l2Device::kPath, small_z16(), device);
  REQUIRE(source.open().ok());
  DepthFrame frame;
  const NextFrame got = source.next(frame);
  REQUIRE(got.outcome == FrameOutcome::frame);
  CHECK(frame_matches(frame, 0));
  CHECK(device.dqbuf_errors.empty());
  CHECK(device.poll_errors.empty());
}

TEST_CASE("v4l2: EIO, flagged and short buffers are skipped and the stream goes on") {
  FakeV4l2Device device;
  device.frames_on_poll = 0;
  V4l2Source source(FakeV4l2Device::kPath, small_z16(), device);
  REQUIRE(source.open().ok());
  DepthFrame frame;

  device.dqbuf_errors = {EIO};
  NextFrame got = source.next(frame);
  CHECK(got.outcome == FrameOutcome::skip);
  CHECK(got.status.code() == StatusCode::data_loss);
  CHECK(contains(source.last_error(), "EIO"));

  REQUIRE(device.capture(100, 0, /*flag_error=*/true));
  got = source.next(frame);
  CHECK(got.outcome == FrameOutcome::skip);
  CHECK(got.status.code() == StatusCode::data_loss);
  CHECK(contains(source.last_error(), "corrupt"));
  CHECK(device.queued_count() == 4);  // the bad buffer went straight back

  REQUIRE(device.capture(200, /*bytesused=*/1000));
  got = source.next(frame);
  CHECK(got.outcome == FrameOutcome::skip);
  CHECK(got.status.code() == StatusCode::data_loss);
  CHECK(contains(source.last_error(), "short: 1000 of"));
  CHECK(device.queued_count() == 4);

  // The last row needs no padding: bytesused may stop right after its last pixel.
  const std::uint32_t tight = device.size_image() - device.row_padding_bytes;
  REQUIRE(device.capture(300, tight));
  got = source.next(frame);
  REQUIRE(got.outcome == FrameOutcome::frame);
  CHECK(frame.sequence == 2);
  CHECK(frame.depth_raw(63, 47) == 300 + 63 + 47);
}

TEST_CASE("v4l2: ENODEV mid-stream gives unavailable and a clean close") {
  FakeV4l2Device device;
  V4l2Source source(FakeV4l2Device::kPath, small_z16(), device);
  REQUIRE(source.open().ok());
  DepthFrame frame;
  REQUIRE(source.next(frame).outcome == FrameOutcome::frame);

  device.disconnect();
  const NextFrame gone = source.next(frame);
  CHECK(gone.outcome == FrameOutcome::error);
  CHECK(gone.status.code() == StatusCode::unavailable);
  CHECK(contains(source.last_error(), "ENODEV"));
  CHECK(device.open_count() == 0);
  CHECK(device.mapped_count() == 0);

  const NextFrame after = source.next(frame);
  CHECK(after.status.code() == StatusCode::failed_precondition);
  source.close();
  CHECK(device.open_count() == 0);
}

TEST_CASE("v4l2: ENODEV seen first through poll also closes cleanly") {
  FakeV4l2Device device;
  device.frames_on_poll = 0;
  V4l2Source source(FakeV4l2Device::kPath, small_z16(), device);
  REQUIRE(source.open().ok());
  device.disconnect();
  DepthFrame frame;
  const NextFrame gone = source.next(frame);
  CHECK(gone.status.code() == StatusCode::unavailable);
  CHECK(device.open_count() == 0);
  CHECK(device.mapped_count() == 0);
}

TEST_CASE("v4l2: timestamps fall back to the monotonic clock when the driver's are not") {
  FakeV4l2Device device;
  device.monotonic_timestamps = false;
  V4l2Source source(FakeV4l2Device::kPath, small_z16(), device);
  REQUIRE(source.open().ok());
  DepthFrame frame;
  REQUIRE(source.next(frame).outcome == FrameOutcome::frame);
  CHECK(frame.timestamp_us == device.now_us());
}

TEST_CASE("v4l2: no heap allocation per frame after open()") {
  FakeV4l2Device device;
  V4l2Source source(FakeV4l2Device::kPath, small_z16(), device);
  REQUIRE(source.open().ok());
  DepthFrame frame;
  int frames = 0;
  int skips = 0;
  test::AllocationScope scope;
  for (int k = 0; k < 300; ++k) {
    if (k % 50 == 25) device.capture(7, 0, true);  // a corrupt frame now and then
    const NextFrame got = source.next(frame);
    frames += got.outcome == FrameOutcome::frame ? 1 : 0;
    skips += got.outcome == FrameOutcome::skip ? 1 : 0;
  }
  CHECK(scope.allocations() == 0);
  CHECK(frames == 294);
  CHECK(skips == 6);
}

}  // namespace
}  // namespace octofuse
