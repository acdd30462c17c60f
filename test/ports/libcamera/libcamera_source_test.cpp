// What can be tested without a camera: these machines have none, so libcamera's camera manager
// starts and lists zero cameras. Streaming is covered by the pixel conversion tests.

#include "octofuse/ports/libcamera/libcamera_source.hpp"

#include <catch2/catch.hpp>
#include <cstdlib>
#include <cstring>
#include <string>

#include "support/text.hpp"

namespace octofuse {
namespace {

using ports::LibcameraOptions;
using ports::LibcameraSource;
using test::contains;

void quiet_libcamera() {
  ::setenv("LIBCAMERA_LOG_LEVELS", "*:ERROR", 0);
}

TEST_CASE("libcamera: with no camera present open() is unavailable with a clear message") {
  quiet_libcamera();
  LibcameraSource source(LibcameraOptions{});
  const Status opened = source.open();
  if (opened.ok()) {
    WARN("a libcamera camera is present here; the zero-camera test does not apply");
    return;
  }
  CHECK(opened.code() == StatusCode::unavailable);
  CHECK(contains(source.last_error(), "no cameras found"));

  DepthFrame frame;
  const NextFrame early = source.next(frame);
  CHECK(early.outcome == FrameOutcome::error);
  CHECK(early.status.code() == StatusCode::failed_precondition);

  // A failed open releases libcamera's one camera manager: the next source can try again.
  LibcameraOptions by_id;
  by_id.camera_id = "/base/no/such/camera";
  LibcameraSource second(by_id);
  CHECK(second.open().code() == StatusCode::unavailable);
  CHECK(contains(second.last_error(), "no cameras found"));
  second.close();
  second.close();
}

TEST_CASE("libcamera: bad options are refused before libcamera is touched") {
  quiet_libcamera();
  LibcameraOptions options;
  options.width = 320;  // height missing
  LibcameraSource source(options);
  CHECK(source.open().code() == StatusCode::invalid_argument);
  CHECK(contains(source.last_error(), "320x0"));

  const std::string long_id(400, 'c');
  LibcameraOptions long_options;
  long_options.camera_id = long_id.c_str();
  LibcameraSource long_source(long_options);
  CHECK(long_source.open().code() == StatusCode::invalid_argument);
}

TEST_CASE("libcamera: capabilities before open describe a live source") {
  LibcameraOptions options;
  options.ring_size = 3;
  LibcameraSource source(options);
  const SourceCapabilities caps = source.capabilities();
  CHECK(caps.live);
  CHECK_FALSE(caps.has_ground_truth);
  CHECK(caps.ring_size == 3);
  CHECK(std::strcmp(ports::libcamera_layout_name(ports::LibcameraPixelLayout::r10_csi2p),
                    "R10_CSI2P") == 0);
}

}  // namespace
}  // namespace octofuse
