// A test-only OpenNI2 driver (OniDriverAPI): one device, octofuse-test://ramp, with a depth sensor
// in four modes that streams the ramp of test_ramp.hpp at the mode's frame rate. It lets the port
// be exercised through the real OpenNI2 runtime (device enumeration, video modes, properties,
// frame buffers, waiting, the recorder) without hardware.

#include <atomic>
#include <chrono>
#include <cstring>
#include <new>
#include <thread>

#define XN_NEW(type, arg) new type(arg)
#define XN_DELETE(p) delete (p)
#include <Driver/OniDriverAPI.h>

#include "test_ramp.hpp"

namespace {

using namespace octofuse::test::oni;

// Frames taken from OpenNI2's frame manager by all streams, for the allocation test.
std::atomic<long long> g_frames_acquired{0};

OniVideoMode g_modes[] = {
    {ONI_PIXEL_FORMAT_DEPTH_1_MM, 640, 480, 30},
    {ONI_PIXEL_FORMAT_DEPTH_1_MM, 320, 240, 30},
    {ONI_PIXEL_FORMAT_DEPTH_100_UM, 640, 480, 30},
    {ONI_PIXEL_FORMAT_DEPTH_100_UM, 320, 240, 60},
};
OniSensorInfo g_sensor = {ONI_SENSOR_DEPTH, 4, g_modes};

bool same_mode(const OniVideoMode& a, const OniVideoMode& b) {
  return a.pixelFormat == b.pixelFormat && a.resolutionX == b.resolutionX &&
         a.resolutionY == b.resolutionY && a.fps == b.fps;
}

class RampStream final : public oni::driver::StreamBase {
 public:
  ~RampStream() override { stop(); }

  OniStatus start() override {
    if (running_) return ONI_STATUS_OK;
    running_ = true;
    thread_ = std::thread([this] { run(); });
    return ONI_STATUS_OK;
  }
  void stop() override {
    running_ = false;
    if (thread_.joinable()) thread_.join();
  }

  OniBool isPropertySupported(int id) override {
    return id == ONI_STREAM_PROPERTY_VIDEO_MODE || id == ONI_STREAM_PROPERTY_HORIZONTAL_FOV ||
           id == ONI_STREAM_PROPERTY_VERTICAL_FOV || id == ONI_STREAM_PROPERTY_MAX_VALUE ||
           id == ONI_STREAM_PROPERTY_MIN_VALUE || id == ONI_STREAM_PROPERTY_MIRRORING ||
           id == ONI_STREAM_PROPERTY_STRIDE || id == ONI_STREAM_PROPERTY_CROPPING;
  }
  OniStatus getProperty(int id, void* data, int* size) override {
    switch (id) {
      case ONI_STREAM_PROPERTY_VIDEO_MODE:
        return put(mode_, data, size);
      case ONI_STREAM_PROPERTY_HORIZONTAL_FOV:
        return put(kHorizontalFov_rad, data, size);
      case ONI_STREAM_PROPERTY_VERTICAL_FOV:
        return put(kVerticalFov_rad, data, size);
      case ONI_STREAM_PROPERTY_MAX_VALUE:
        return put(mode_.pixelFormat == ONI_PIXEL_FORMAT_DEPTH_1_MM ? 10000 : 65535, data, size);
      case ONI_STREAM_PROPERTY_MIN_VALUE:
        return put(0, data, size);
      case ONI_STREAM_PROPERTY_MIRRORING:
        return put(OniBool{FALSE}, data, size);
      // libOniFile's player drops every frame of a recording that lacks stride or cropping.
      case ONI_STREAM_PROPERTY_STRIDE:
        return put(mode_.resolutionX * 2, data, size);
      case ONI_STREAM_PROPERTY_CROPPING:
        return put(OniCropping{FALSE, 0, 0, mode_.resolutionX, mode_.resolutionY}, data, size);
      default:
        return ONI_STATUS_NOT_SUPPORTED;
    }
  }
  OniStatus setProperty(int id, const void* data, int size) override {
    if (id != ONI_STREAM_PROPERTY_VIDEO_MODE) return ONI_STATUS_NOT_SUPPORTED;
    if (size != sizeof(OniVideoMode) || running_) return ONI_STATUS_BAD_PARAMETER;
    const auto* wanted = static_cast<const OniVideoMode*>(data);
    for (const OniVideoMode& m : g_modes) {
      if (same_mode(m, *wanted)) {
        mode_ = m;
        raisePropertyChanged(id, &mode_, sizeof(mode_));
        return ONI_STATUS_OK;
      }
    }
    return ONI_STATUS_NOT_SUPPORTED;
  }
  void notifyAllProperties() override {
    const int ids[] = {ONI_STREAM_PROPERTY_VIDEO_MODE,   ONI_STREAM_PROPERTY_HORIZONTAL_FOV,
                       ONI_STREAM_PROPERTY_VERTICAL_FOV, ONI_STREAM_PROPERTY_MAX_VALUE,
                       ONI_STREAM_PROPERTY_MIN_VALUE,    ONI_STREAM_PROPERTY_MIRRORING,
                       ONI_STREAM_PROPERTY_STRIDE,       ONI_STREAM_PROPERTY_CROPPING};
    for (int id : ids) {
      // Large enough for every property listed (OniCropping is the largest, 20 bytes).
      alignas(8) unsigned char value[sizeof(OniVideoMode) + sizeof(OniCropping)];
      int size = sizeof(value);
      if (getProperty(id, value, &size) == ONI_STATUS_OK) raisePropertyChanged(id, value, size);
    }
  }

 private:
  template <typename T>
  static OniStatus put(const T& value, void* data, int* size) {
    if (*size < static_cast<int>(sizeof(T))) return ONI_STATUS_BAD_PARAMETER;
    std::memcpy(data, &value, sizeof(T));
    *size = sizeof(T);
    return ONI_STATUS_OK;
  }

  void run() {
    const OniVideoMode mode = mode_;
    const int units_per_mm = mode.pixelFormat == ONI_PIXEL_FORMAT_DEPTH_1_MM ? 1 : 10;
    const auto period = std::chrono::microseconds(1000000 / mode.fps);
    auto tick = std::chrono::steady_clock::now();
    for (int index = kFirstFrameIndex; running_; ++index) {
      tick += period;
      std::this_thread::sleep_until(tick);
      OniFrame* frame = getServices().acquireFrame();
      g_frames_acquired.fetch_add(1);
      if (frame == nullptr) continue;  // no buffer: the frame is dropped, as hardware would
      auto* pixels = static_cast<uint16_t*>(frame->data);
      for (int v = 0; v < mode.resolutionY; ++v) {
        for (int u = 0; u < mode.resolutionX; ++u) {
          pixels[v * mode.resolutionX + u] =
              static_cast<uint16_t>(ramp_depth_mm(u, v, index) * units_per_mm);
        }
      }
      frame->dataSize = mode.resolutionX * mode.resolutionY * 2;
      frame->sensorType = ONI_SENSOR_DEPTH;
      frame->timestamp = static_cast<uint64_t>(ramp_timestamp_us(index, mode.fps));
      frame->frameIndex = index;
      frame->width = mode.resolutionX;
      frame->height = mode.resolutionY;
      frame->videoMode = mode;
      frame->croppingEnabled = FALSE;
      frame->cropOriginX = 0;
      frame->cropOriginY = 0;
      frame->stride = mode.resolutionX * 2;
      raiseNewFrame(frame);
      getServices().releaseFrame(frame);
    }
  }

  OniVideoMode mode_ = g_modes[0];
  std::atomic<bool> running_{false};
  std::thread thread_;
};

class RampDevice final : public oni::driver::DeviceBase {
 public:
  OniStatus getSensorInfoList(OniSensorInfo** infos, int* count) override {
    *infos = &g_sensor;
    *count = 1;
    return ONI_STATUS_OK;
  }
  oni::driver::StreamBase* createStream(OniSensorType type) override {
    return type == ONI_SENSOR_DEPTH ? new RampStream() : nullptr;
  }
  void destroyStream(oni::driver::StreamBase* stream) override { delete stream; }
  // Registration is off and cannot be switched on: there is no colour sensor.
  OniBool isPropertySupported(int id) override {
    return id == ONI_DEVICE_PROPERTY_IMAGE_REGISTRATION;
  }
  OniStatus getProperty(int id, void* data, int* size) override {
    if (id != ONI_DEVICE_PROPERTY_IMAGE_REGISTRATION || *size < static_cast<int>(sizeof(int)))
      return ONI_STATUS_NOT_SUPPORTED;
    const OniImageRegistrationMode off = ONI_IMAGE_REGISTRATION_OFF;
    std::memcpy(data, &off, sizeof(off));
    *size = sizeof(off);
    return ONI_STATUS_OK;
  }
  OniStatus setProperty(int id, const void* data, int size) override {
    if (id != ONI_DEVICE_PROPERTY_IMAGE_REGISTRATION || size != sizeof(OniImageRegistrationMode))
      return ONI_STATUS_NOT_SUPPORTED;
    return *static_cast<const OniImageRegistrationMode*>(data) == ONI_IMAGE_REGISTRATION_OFF
               ? ONI_STATUS_OK
               : ONI_STATUS_NOT_SUPPORTED;
  }
};

class RampDriver final : public oni::driver::DriverBase {
 public:
  explicit RampDriver(OniDriverServices* services) : DriverBase(services) {
    std::strncpy(info_.uri, kUri, sizeof(info_.uri) - 1);
    std::strncpy(info_.vendor, "octofuse", sizeof(info_.vendor) - 1);
    std::strncpy(info_.name, "test ramp", sizeof(info_.name) - 1);
  }
  OniStatus initialize(oni::driver::DeviceConnectedCallback connected,
                       oni::driver::DeviceDisconnectedCallback disconnected,
                       oni::driver::DeviceStateChangedCallback state_changed,
                       void* cookie) override {
    const OniStatus status = DriverBase::initialize(connected, disconnected, state_changed, cookie);
    if (status == ONI_STATUS_OK) deviceConnected(&info_);
    return status;
  }
  oni::driver::DeviceBase* deviceOpen(const char* uri, const char* /*mode*/) override {
    return std::strcmp(uri, kUri) == 0 ? new RampDevice() : nullptr;
  }
  void deviceClose(oni::driver::DeviceBase* device) override { delete device; }
  void shutdown() override {}
  OniStatus tryDevice(const char* uri) override {
    return std::strncmp(uri, kUriPrefix, std::strlen(kUriPrefix)) == 0 ? ONI_STATUS_OK
                                                                       : ONI_STATUS_ERROR;
  }

 private:
  OniDeviceInfo info_{};
};

}  // namespace

ONI_EXPORT_DRIVER(RampDriver)

ONI_C_API_EXPORT long long octofuse_test_driver_frames_acquired();
ONI_C_API_EXPORT long long octofuse_test_driver_frames_acquired() {
  return g_frames_acquired.load();
}
