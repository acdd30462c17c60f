// The MCAP bag reader against bags an independent writer (make_bag.py) made from sim and
// 7-Scenes frames: the same pixels, timestamps, intrinsics and poses, the same trajectory, every
// compression and layout, cuts at any byte, and bad input answered with one clear error.

#include <algorithm>
#include <catch2/catch.hpp>
#include <cmath>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "bag_fixtures.hpp"
#include "octofuse/pipeline/mapper.hpp"
#include "octofuse/ports/replay/bag_reader.hpp"
#include "octofuse/ports/replay/bag_source.hpp"
#include "octofuse/ports/replay/replay_source.hpp"
#include "octofuse/ports/sim/sim_source.hpp"
#include "support/alloc_counter.hpp"
#include "support/small_sim.hpp"
#include "support/test_data.hpp"
#include "support/test_dir.hpp"

using octofuse::FrameOutcome;
using octofuse::NextFrame;
using octofuse::StatusCode;
using octofuse::replay::BagConfig;
using octofuse::replay::BagSource;
using namespace octofuse::test;

namespace {

constexpr int kSimFrames = 5;

KeptFrames sim_frames() {
  octofuse::sim::SimSource sim(small_sim(kSimFrames));
  REQUIRE(sim.open().ok());
  return keep_frames(sim, kSimFrames);
}

std::unique_ptr<BagSource> open_bag(const std::string& path, const char* query = "",
                                    const char* scheme = "mcap:") {
  BagConfig config;
  octofuse::ErrorText error;
  const std::string spec = scheme + path + query;
  REQUIRE(octofuse::replay::parse_bag_spec(spec.c_str(), &config, &error).ok());
  return std::make_unique<BagSource>(config);
}

// Every frame of the bag equals the kept one; `units_ratio` is bag units per kept unit (32FC1
// bags are stored at 5000 units/m, sim frames in millimetres).
void check_same_frames(BagSource& bag, const KeptFrames& kept, int units_ratio, bool poses,
                       double pose_tolerance = 1e-12) {
  const octofuse::PinholeCamera camera = bag.intrinsics();
  CHECK(camera.fx == kept.camera.fx);
  CHECK(camera.fy == kept.camera.fy);
  CHECK(camera.cx == kept.camera.cx);
  CHECK(camera.cy == kept.camera.cy);
  CHECK(camera.width == kept.camera.width);
  CHECK(camera.height == kept.camera.height);
  CHECK(bag.capabilities().has_ground_truth == poses);
  octofuse::DepthFrame frame;
  for (const KeptFrame& k : kept.frames) {
    const NextFrame next = bag.next(frame);
    INFO(bag.last_error());
    REQUIRE(next.outcome == FrameOutcome::frame);
    CHECK(frame.timestamp_us == k.timestamp_us);
    REQUIRE(frame.depth_raw.width == k.width);
    REQUIRE(frame.depth_raw.height == k.height);
    int differing = 0;
    for (int y = 0; y < k.height; ++y) {
      for (int x = 0; x < k.width; ++x) {
        const int want = k.depth[static_cast<std::size_t>(y) * k.width + x] * units_ratio;
        differing += frame.depth_raw(x, y) != want;
      }
    }
    CHECK(differing == 0);
    if (units_ratio == 1) CHECK(frame.metres_per_unit == k.metres_per_unit);
    CHECK(frame.has_ground_truth == (poses && k.has_pose));
    if (poses && k.has_pose)
      CHECK((frame.T_W_C_ground_truth - k.T_W_C).cwiseAbs().maxCoeff() < pose_tolerance);
  }
  const NextFrame end = bag.next(frame);
  CHECK(end.outcome == FrameOutcome::end_of_stream);
  CHECK(end.status.code() == StatusCode::end_of_stream);
}

// The first `count` frames of a source without their ground truth: the Mapper then starts both
// runs at the same given pose (the bag's poses went through quaternions, a few 1e-17 off).
struct Tracked final : octofuse::DepthSource {
  octofuse::DepthSource* inner;
  int left;
  Tracked(octofuse::DepthSource* s, int n) : inner(s), left(n) {}
  octofuse::Status open() override { return octofuse::ok_status(); }
  NextFrame next(octofuse::DepthFrame& f) override {
    if (left-- <= 0) return NextFrame::ended();
    const NextFrame got = inner->next(f);
    f.has_ground_truth = false;
    return got;
  }
  void close() override {}
  octofuse::PinholeCamera intrinsics() const override { return inner->intrinsics(); }
  octofuse::SourceCapabilities capabilities() const override { return inner->capabilities(); }
  const char* last_error() const override { return inner->last_error(); }
};

// The camera poses a Mapper tracks over the frames, all from the same first pose.
std::vector<Eigen::Matrix4d> track(octofuse::DepthSource& inner,
                                   const octofuse::PinholeCamera& camera,
                                   const Eigen::Matrix4d& first_T_W_C, int count = 1000) {
  Tracked source(&inner, count);
  octofuse::MapperSettings settings;
  settings.first_T_W_C = octofuse::Se3d(first_T_W_C);
  settings.threads = 1;
  octofuse::Mapper<> mapper;
  REQUIRE(mapper.init(camera, settings).ok());
  std::vector<Eigen::Matrix4d> poses;
  octofuse::DepthFrame frame;
  octofuse::FrameStats stats;
  while (source.next(frame).outcome == FrameOutcome::frame) {
    (void)mapper.process(frame, &stats);
    poses.push_back(mapper.T_W_C().matrix());
  }
  return poses;
}

}  // namespace

TEST_CASE("mcap: sim frames come back the same in every layout and compression", "[replay][bag]") {
  Fixture fixture(sim_frames());
  struct Variant {
    const char* options;
    int units_ratio;
    bool poses;
  };
  const Variant variants[] = {
      {"--compression zstd", 1, true},
      {"--compression lz4", 1, true},
      {"--compression none", 1, true},
      {"--unchunked --no-summary", 1, true},
      {"--compression zstd --no-summary --pose odometry", 1, true},
      {"--unchunked --pose pose_stamped --encoding mono16 --big-endian", 1, true},
      {"--compression lz4 --pose none --extra-image", 1, false},
      {"--encoding 32FC1", 5, true},
      {"--encoding 32FC1 --big-endian --compression zstd", 5, true},
      {"--compressed png --compression none", 1, true},
      {"--compressed rvl --compression lz4 --pose odometry", 1, true},
  };
  int n = 0;
  for (const Variant& v : variants) {
    INFO(v.options);
    const std::string path = fixture.bag("v" + std::to_string(n++) + ".mcap", v.options);
    if (path.empty()) continue;
    std::unique_ptr<BagSource> bag = open_bag(path);
    {
      const octofuse::Status opened = bag->open();
      INFO(bag->last_error());
      REQUIRE(opened.ok());
    }
    CHECK(std::strncmp(bag->depth_topic(), "/camera/depth/image_raw", 23) == 0);
    check_same_frames(*bag, fixture.kept, v.units_ratio, v.poses);
    CHECK(bag->frames_without_pose() == 0);
  }
}

TEST_CASE("mcap: compressedDepth of 32FC1 comes back within its quantisation", "[replay][bag]") {
  Fixture fixture(sim_frames());
  for (const char* codec : {"png", "rvl"}) {
    INFO(codec);
    const std::string path = fixture.bag(std::string(codec) + ".mcap",
                                         std::string("--encoding 32FC1 --compressed ") + codec);
    std::unique_ptr<BagSource> bag = open_bag(path);
    REQUIRE(bag->open().ok());
    octofuse::DepthFrame frame;
    for (const KeptFrame& k : fixture.kept.frames) {
      REQUIRE(bag->next(frame).outcome == FrameOutcome::frame);
      int outside = 0;
      for (std::size_t i = 0; i < k.depth.size(); ++i) {
        const double want_m = k.depth[i] * static_cast<double>(k.metres_per_unit);
        const double got_m = frame.depth_raw.data[i] * static_cast<double>(frame.metres_per_unit);
        // Inverse depth in 16 bits with A = 10100: a step of d^2 / A metres at depth d.
        const double step_m = want_m * want_m / 10100.0;
        outside += (k.depth[i] == 0) != (frame.depth_raw.data[i] == 0) ||
                   std::fabs(got_m - want_m) > step_m + 2e-4;
      }
      CHECK(outside == 0);
    }
  }
}

TEST_CASE("mcap: next() after open() does not allocate", "[replay][bag]") {
  if (!octofuse::test::counts_malloc()) return;  // the sanitizers own malloc
  Fixture fixture(sim_frames());
  for (const char* options : {"--compression zstd", "--compression lz4", "--unchunked",
                              "--compressed png", "--compressed rvl --compression zstd"}) {
    INFO(options);
    const std::string path = fixture.bag("alloc.mcap", options);
    if (path.empty()) continue;
    std::unique_ptr<BagSource> bag = open_bag(path);
    REQUIRE(bag->open().ok());
    octofuse::DepthFrame frame;
    int frames = 0;
    // open() read the whole bag once: the decompressors' buffers are already there.
    octofuse::test::AllocationScope scope;
    while (bag->next(frame).outcome == FrameOutcome::frame) ++frames;
    CHECK(scope.allocations() == 0);
    CHECK(frames == kSimFrames);
  }
}

TEST_CASE("mcap: a bag's odometry poses for the prior", "[replay][bag]") {
  Fixture fixture(sim_frames());
  struct Collected {
    std::vector<std::int64_t> stamps_ns;
    std::vector<Eigen::Matrix4d> poses;
  } collected;
  auto collect = [](void* context, std::int64_t stamp_ns, const octofuse::Se3d& T) {
    static_cast<Collected*>(context)->stamps_ns.push_back(stamp_ns);
    static_cast<Collected*>(context)->poses.push_back(T.matrix());
  };
  octofuse::ErrorText error;
  BagConfig config;
  for (const char* kind : {"odometry", "pose_stamped"}) {
    INFO(kind);
    collected = Collected();
    const std::string path =
        fixture.bag(std::string(kind) + ".mcap", std::string("--compression none --pose ") + kind);
    REQUIRE(octofuse::replay::parse_bag_spec(("mcap:" + path).c_str(), &config, &error).ok());
    REQUIRE(octofuse::replay::read_bag_poses(config, collect, &collected, &error).ok());
    REQUIRE(collected.poses.size() == fixture.kept.frames.size());
    for (std::size_t i = 0; i < collected.poses.size(); ++i) {
      CHECK(collected.stamps_ns[i] == fixture.kept.frames[i].timestamp_us * 1000);
      CHECK((collected.poses[i] - fixture.kept.frames[i].T_W_C).cwiseAbs().maxCoeff() < 1e-12);
    }
  }
  // A bag with TF only has no odometry topic: one clear error.
  const std::string tf = fixture.bag("tf.mcap", "--compression none --pose tf");
  REQUIRE(octofuse::replay::parse_bag_spec(("mcap:" + tf).c_str(), &config, &error).ok());
  CHECK(octofuse::replay::read_bag_poses(config, collect, &collected, &error).code() ==
        StatusCode::invalid_argument);
  CHECK(std::strstr(error.c_str(), "no Odometry or PoseStamped") != nullptr);
}

// make_bag.py's --pose odom_tf: map -> odom (MAP_ODOM) -> body -> camera_depth (BODY_CAMERA).
namespace {
Eigen::Matrix4d map_odom() {
  const double c = std::cos(30.0 * M_PI / 180.0), s = std::sin(30.0 * M_PI / 180.0);
  Eigen::Matrix4d T;
  T << c, -s, 0, 1.0, s, c, 0, 2.0, 0, 0, 1, 0, 0, 0, 0, 1;
  return T;
}
}  // namespace

TEST_CASE("bag: the odometry prior from a robot's TF tree (map -> odom -> body -> camera)",
          "[replay][bag][rosbag]") {
  Fixture fixture(sim_frames());
  struct Collected {
    std::vector<std::int64_t> stamps_ns;
    std::vector<Eigen::Matrix4d> poses;
  } collected;
  auto collect = [](void* context, std::int64_t stamp_ns, const octofuse::Se3d& T) {
    static_cast<Collected*>(context)->stamps_ns.push_back(stamp_ns);
    static_cast<Collected*>(context)->poses.push_back(T.matrix());
  };
  const Eigen::Matrix4d odom_map = map_odom().inverse();
  std::vector<std::string> specs;
  const std::string mcap = fixture.bag("odom_tf.mcap", "--compression none --pose odom_tf");
  if (!mcap.empty()) specs.push_back("mcap:" + mcap);
  const std::string ros1 = fixture.rosbag("odom_tf.bag", "--compression lz4 --pose odom_tf");
  if (!ros1.empty()) specs.push_back("rosbag:" + ros1);
  for (const std::string& spec : specs) {
    // The odom frame found on the chain, or named; the map frame named gives the ground truth.
    for (const char* query : {"", "?tf=odom", "?tf=/odom", "?tf=map"}) {
      INFO(spec << query);
      const bool map = std::strcmp(query, "?tf=map") == 0;
      BagConfig config;
      octofuse::ErrorText error;
      REQUIRE(octofuse::replay::parse_bag_spec((spec + query).c_str(), &config, &error).ok());
      collected = Collected();
      REQUIRE(octofuse::replay::read_bag_poses(config, collect, &collected, &error).ok());
      REQUIRE(collected.poses.size() == fixture.kept.frames.size());
      for (std::size_t i = 0; i < collected.poses.size(); ++i) {
        const KeptFrame& k = fixture.kept.frames[i];
        CHECK(collected.stamps_ns[i] == k.timestamp_us * 1000);
        const Eigen::Matrix4d want = map ? k.T_W_C : Eigen::Matrix4d(odom_map * k.T_W_C);
        CHECK((collected.poses[i] - want).cwiseAbs().maxCoeff() < 1e-9);
      }
    }
    {  // a frame that is not on the chain: one clear error naming the chain
      BagConfig config;
      octofuse::ErrorText error;
      REQUIRE(
          octofuse::replay::parse_bag_spec((spec + "?tf=base_link").c_str(), &config, &error).ok());
      CHECK(octofuse::replay::read_bag_poses(config, collect, &collected, &error).code() ==
            StatusCode::invalid_argument);
      CHECK(std::strstr(error.c_str(),
                        "to 'base_link' (the chain: camera_depth -> body -> odom "
                        "-> map)") != nullptr);
    }
    // As the source, the same TF gives the ground truth (chained to the root, map).
    std::unique_ptr<BagSource> bag =
        open_bag(spec.substr(spec.find(':') + 1), "", spec.substr(0, spec.find(':') + 1).c_str());
    REQUIRE(bag->open().ok());
    check_same_frames(*bag, fixture.kept, 1, true, 1e-9);
  }
  {  // TF without an odom frame (world -> body -> camera): the error says how to name one
    const std::string path = fixture.bag("tf_world.mcap", "--compression none --pose tf");
    BagConfig config;
    octofuse::ErrorText error;
    REQUIRE(octofuse::replay::parse_bag_spec(("mcap:" + path).c_str(), &config, &error).ok());
    CHECK(octofuse::replay::read_bag_poses(config, collect, &collected, &error).code() ==
          StatusCode::invalid_argument);
    CHECK(std::strstr(error.c_str(),
                      "(camera_depth -> body -> world) has no 'odom' frame; name "
                      "the odometry's frame with mcap:FILE?tf=FRAME") != nullptr);
    REQUIRE(
        octofuse::replay::parse_bag_spec(("mcap:" + path + "?tf=world").c_str(), &config, &error)
            .ok());
    collected = Collected();
    REQUIRE(octofuse::replay::read_bag_poses(config, collect, &collected, &error).ok());
    REQUIRE(collected.poses.size() == fixture.kept.frames.size());
    for (std::size_t i = 0; i < collected.poses.size(); ++i) {
      CHECK((collected.poses[i] - fixture.kept.frames[i].T_W_C).cwiseAbs().maxCoeff() < 1e-9);
    }
  }
}

TEST_CASE("bag: chunks that overlap in time are read in log-time order", "[replay][bag][rosbag]") {
  Fixture fixture(sim_frames());
  // The pose topic chunked apart from the camera's: in the file, the TF of later frames comes
  // before a frame's image (make_bag.py / make_rosbag.py --overlap).
  std::vector<std::string> specs;
  const std::string mcap = fixture.bag("overlap.mcap", "--compression none --overlap");
  if (!mcap.empty()) specs.push_back("mcap:" + mcap);
  const std::string ros1 =
      fixture.rosbag("overlap.bag", "--compression none --overlap --chunk-threshold 1");
  if (!ros1.empty()) specs.push_back("rosbag:" + ros1);
  for (const std::string& spec : specs) {
    INFO(spec);
    const std::string scheme = spec.substr(0, spec.find(':') + 1);
    const std::string path = spec.substr(spec.find(':') + 1);
    const octofuse::replay::BagFormat format =
        scheme == "mcap:" ? octofuse::replay::BagFormat::mcap : octofuse::replay::BagFormat::rosbag;
    {  // the container in file order: log times go back
      octofuse::replay::McapLimits limits;
      limits.reorder_bytes = 0;
      octofuse::replay::BagReader reader;
      REQUIRE(reader.open(path.c_str(), format, limits).ok());
      octofuse::replay::McapMessage message;
      while (reader.next(&message) == octofuse::replay::McapNext::message) {
      }
      CHECK(reader.out_of_order() > 0);
    }
    {  // through the window: every message, in log-time order, none late
      octofuse::replay::BagReader reader;
      REQUIRE(reader.open(path.c_str(), format, octofuse::replay::McapLimits()).ok());
      octofuse::replay::McapMessage message;
      std::uint64_t last_ns = 0;
      int messages = 0, backwards = 0;
      octofuse::replay::McapNext got;
      while ((got = reader.next(&message)) == octofuse::replay::McapNext::message) {
        backwards += message.log_time_ns < last_ns;
        last_ns = message.log_time_ns;
        ++messages;
      }
      CHECK(got == octofuse::replay::McapNext::end);
      CHECK(backwards == 0);
      CHECK(reader.out_of_order() == 0);
      CHECK(messages >= 3 * kSimFrames);
    }
    // The source: each frame with its own pose, the stream ending without a warning.
    std::unique_ptr<BagSource> bag = open_bag(path, "", scheme.c_str());
    REQUIRE(bag->open().ok());
    CHECK(bag->scan_warning()[0] == '\0');
    check_same_frames(*bag, fixture.kept, 1, true, 1e-9);
    // In file order (reorder=0) the run is told; poses still go by stamp, not by arrival, so
    // each frame keeps its own (the transforms that came early wait in the TF table).
    for (const char* query : {"?reorder=0", "?tiny"}) {
      INFO(query);
      BagConfig config;
      octofuse::ErrorText error;
      if (std::strcmp(query, "?tiny") == 0) {
        // A window smaller than any message: as good as file order, and said to be too small.
        REQUIRE(octofuse::replay::parse_bag_spec(spec.c_str(), &config, &error).ok());
        config.limits.reorder_bytes = 64;
      } else {
        REQUIRE(octofuse::replay::parse_bag_spec((spec + query).c_str(), &config, &error).ok());
      }
      BagSource file_order(config);
      REQUIRE(file_order.open().ok());
      CHECK(std::strstr(file_order.scan_warning(), "messages out of log-time order") != nullptr);
      octofuse::DepthFrame frame;
      int frames = 0, wrong_pose = 0;
      NextFrame next;
      while ((next = file_order.next(frame)).outcome == FrameOutcome::frame) {
        const KeptFrame& k = fixture.kept.frames[static_cast<std::size_t>(frames++)];
        wrong_pose += !frame.has_ground_truth ||
                      (frame.T_W_C_ground_truth - k.T_W_C).cwiseAbs().maxCoeff() > 1e-6;
      }
      CHECK(frames == kSimFrames);
      CHECK(wrong_pose == 0);
      CHECK(next.outcome == FrameOutcome::end_of_stream);
      CHECK(next.status.code() == StatusCode::out_of_range);
      INFO(file_order.last_error());
      CHECK(std::strstr(file_order.last_error(),
                        query[1] == 'r'
                            ? "out of log-time order (reorder=0)"
                            : "beyond the 64 byte reorder window (?reorder=MB)") != nullptr);
    }
  }
}

TEST_CASE("mcap: a bag of sim frames gives the same trajectory as the sim", "[replay][bag]") {
  Fixture fixture(sim_frames());
  const std::string path = fixture.bag("same.mcap", "--compression zstd");
  if (path.empty()) return;
  octofuse::sim::SimSource sim(small_sim(kSimFrames));
  REQUIRE(sim.open().ok());
  std::unique_ptr<BagSource> bag = open_bag(path);
  REQUIRE(bag->open().ok());
  const Eigen::Matrix4d first = fixture.kept.frames[0].T_W_C;
  const std::vector<Eigen::Matrix4d> from_sim = track(sim, sim.intrinsics(), first);
  const std::vector<Eigen::Matrix4d> from_bag = track(*bag, bag->intrinsics(), first);
  REQUIRE(from_sim.size() == static_cast<std::size_t>(kSimFrames));
  REQUIRE(from_bag.size() == from_sim.size());
  for (std::size_t i = 0; i < from_sim.size(); ++i) CHECK(from_bag[i] == from_sim[i]);
}

TEST_CASE("mcap: a bag cut at any byte replays to its last whole message", "[replay][bag]") {
  Fixture fixture(sim_frames());
  for (const char* options : {"--compression zstd", "--compression lz4", "--compression none",
                              "--unchunked --no-summary"}) {
    INFO(options);
    const std::string whole = fixture.bag("whole.mcap", options);
    if (whole.empty()) continue;
    const std::string bytes = read_bytes(whole);
    const std::string cut = fixture.dir + "/cut.mcap";
    std::size_t previous_frames = 0;
    for (std::size_t size = 0; size < bytes.size(); size += 1 + size / 8) {
      INFO("cut at " << size);
      write_text(cut, bytes.substr(0, size));
      std::unique_ptr<BagSource> bag = open_bag(cut);
      const octofuse::Status opened = bag->open();
      if (!opened.ok()) {
        // Cut before a whole camera info and image: one clear error, and no frame later on.
        CHECK(std::strlen(bag->last_error()) > 0);
        CHECK(previous_frames == 0);
        continue;
      }
      octofuse::DepthFrame frame;
      std::size_t frames = 0;
      NextFrame next;
      while ((next = bag->next(frame)).outcome == FrameOutcome::frame) {
        const KeptFrame& k = fixture.kept.frames.at(frames);
        CHECK(frame.timestamp_us == k.timestamp_us);
        CHECK(std::memcmp(frame.depth_raw.data, k.depth.data(), k.depth.size() * 2) == 0);
        ++frames;
      }
      CHECK(next.outcome == FrameOutcome::end_of_stream);
      if (next.status.code() == StatusCode::end_of_stream) {
        // Cut after the data section: only the summary, which replay does not need, is lost.
        CHECK(frames == fixture.kept.frames.size());
      } else {
        CHECK(next.status.code() == StatusCode::data_loss);
        CHECK(std::strstr(bag->last_error(), "cut short at byte") != nullptr);
      }
      CHECK(frames >= previous_frames);
      previous_frames = frames;
    }
    CHECK(previous_frames + 1 >= fixture.kept.frames.size());
  }
}

TEST_CASE("mcap: bad input gets one clear error", "[replay][bag]") {
  Fixture fixture(sim_frames());
  SECTION("distortion it cannot honour") {
    const std::string path = fixture.bag("d.mcap", "--distortion 0.25");
    std::unique_ptr<BagSource> bag = open_bag(path);
    CHECK(bag->open().code() == StatusCode::invalid_argument);
    CHECK(std::strstr(bag->last_error(), "plumb_bob distortion") != nullptr);
  }
  SECTION("a flipped byte in a chunk fails its CRC") {
    const std::string path = fixture.bag("c.mcap", "--compression none");
    std::string bytes = read_bytes(path);
    bytes[bytes.size() / 2] = static_cast<char>(bytes[bytes.size() / 2] ^ 0x40);
    write_text(path, bytes);
    std::unique_ptr<BagSource> bag = open_bag(path);
    CHECK(bag->open().code() == StatusCode::data_loss);
    CHECK(std::strstr(bag->last_error(), "CRC mismatch") != nullptr);
  }
  SECTION("not an MCAP file") {
    const std::string path = fixture.dir + "/x.mcap";
    write_text(path, "not a bag at all");
    std::unique_ptr<BagSource> bag = open_bag(path);
    CHECK(bag->open().code() == StatusCode::data_loss);
    CHECK(std::strstr(bag->last_error(), "not an MCAP file") != nullptr);
  }
  SECTION("a missing file") {
    std::unique_ptr<BagSource> bag = open_bag(fixture.dir + "/none.mcap");
    CHECK(bag->open().code() == StatusCode::unavailable);
  }
  SECTION("a chunk larger than the buffer: the error says how to raise it") {
    const std::string path = fixture.bag("b.mcap", "--compression zstd");
    if (path.empty()) return;
    octofuse::replay::McapReader reader;
    octofuse::replay::McapLimits limits;
    limits.max_chunk_bytes = 4096;  // a 160 x 120 frame decompresses to 38 kB
    REQUIRE(reader.open(path.c_str(), limits).ok());
    octofuse::replay::McapMessage message;
    octofuse::replay::McapNext got;
    while ((got = reader.next(&message)) == octofuse::replay::McapNext::message) {
    }
    CHECK(got == octofuse::replay::McapNext::error);
    CHECK(std::strstr(reader.error(), "raise it with ?buffer=MB") != nullptr);
  }
  SECTION("a depth topic that is not there") {
    const std::string path = fixture.bag("t.mcap", "--compression none");
    std::unique_ptr<BagSource> bag = open_bag(path, "?depth=/nope");
    CHECK(bag->open().code() == StatusCode::invalid_argument);
    CHECK(std::strstr(bag->last_error(), "/nope") != nullptr);
  }
  SECTION("a TF chain to a world frame that is not there: frames without a pose, counted") {
    const std::string path = fixture.bag("w.mcap", "--compression none");
    std::unique_ptr<BagSource> bag = open_bag(path, "?world=map");
    REQUIRE(bag->open().ok());
    octofuse::DepthFrame frame;
    int frames = 0;
    while (bag->next(frame).outcome == FrameOutcome::frame) {
      CHECK_FALSE(frame.has_ground_truth);
      ++frames;
    }
    CHECK(bag->frames_without_pose() == static_cast<std::uint64_t>(frames));
    CHECK(frames == kSimFrames);
  }
  SECTION("spec options") {
    BagConfig config;
    octofuse::ErrorText error;
    CHECK(octofuse::replay::parse_bag_spec("mcap:a.mcap?depth=/d&info=/i&pose=/tf&world=map",
                                           &config, &error)
              .ok());
    CHECK(std::strcmp(config.path, "a.mcap") == 0);
    CHECK(std::strcmp(config.depth_topic, "/d") == 0);
    CHECK(std::strcmp(config.info_topic, "/i") == 0);
    CHECK(std::strcmp(config.pose_topic, "/tf") == 0);
    CHECK(std::strcmp(config.world_frame, "map") == 0);
    CHECK(octofuse::replay::parse_bag_spec("mcap:a?buffer=2", &config, &error).ok());
    CHECK(config.limits.max_chunk_bytes == 2u << 20);
    CHECK(octofuse::replay::parse_bag_spec("mcap:a?buffer=0", &config, &error).code() ==
          StatusCode::invalid_argument);
    CHECK(octofuse::replay::parse_bag_spec("mcap:a?reorder=0", &config, &error).ok());
    CHECK(config.limits.reorder_bytes == 0u);
    CHECK(octofuse::replay::parse_bag_spec("mcap:a?reorder=4096", &config, &error).ok());
    CHECK(config.limits.reorder_bytes == std::size_t{4096} << 20);
    for (const char* bad :
         {"mcap:a?reorder=", "mcap:a?reorder=-1", "mcap:a?reorder=4097", "mcap:a?reorder=3x",
          "mcap:a?buffer=", "mcap:a?buffer=1025", "mcap:a?buffer=12345678901234567890"}) {
      CAPTURE(bad);
      CHECK(octofuse::replay::parse_bag_spec(bad, &config, &error).code() ==
            StatusCode::invalid_argument);
    }
    CHECK(octofuse::replay::parse_bag_spec("mcap:", &config, &error).code() ==
          StatusCode::invalid_argument);
    CHECK(octofuse::replay::parse_bag_spec("mcap:a?colour=x", &config, &error).code() ==
          StatusCode::invalid_argument);
    CHECK(octofuse::replay::parse_bag_spec("mcap:a?depth=", &config, &error).code() ==
          StatusCode::invalid_argument);
  }
}

TEST_CASE("mcap: a bag of 7-Scenes frames gives their trajectory", "[replay][bag][data]") {
  std::string why;
  const std::string recording = octofuse::test::recording_dir("7scenes-redkitchen", &why);
  if (recording.empty()) {
    WARN(why << ": skipping the 7-Scenes bag test");
    return;
  }
  constexpr int kFrames = 4;
  const std::string spec = "7scenes:" + recording;
  octofuse::replay::ReplayConfig config;
  octofuse::ErrorText error;
  REQUIRE(octofuse::replay::parse_replay_spec(spec.c_str(), &config, &error).ok());
  octofuse::replay::ReplaySource seven(config);
  REQUIRE(seven.open().ok());
  Fixture fixture(keep_frames(seven, kFrames));
  const std::string path = fixture.bag("7scenes.mcap", "--compression lz4");
  if (path.empty()) return;
  std::unique_ptr<BagSource> bag = open_bag(path);
  REQUIRE(bag->open().ok());
  // 7-Scenes' rotations are orthonormal to about 6e-5 only; a quaternion makes them exact.
  check_same_frames(*bag, fixture.kept, 1, true, 1e-4);

  octofuse::replay::ReplaySource again(config);
  REQUIRE(again.open().ok());
  std::unique_ptr<BagSource> bag_again = open_bag(path);
  REQUIRE(bag_again->open().ok());
  const Eigen::Matrix4d first = fixture.kept.frames[0].T_W_C;
  const std::vector<Eigen::Matrix4d> from_folder = track(again, again.intrinsics(), first, kFrames);
  const std::vector<Eigen::Matrix4d> from_bag = track(*bag_again, bag_again->intrinsics(), first);
  REQUIRE(from_bag.size() == from_folder.size());
  for (std::size_t i = 0; i < from_bag.size(); ++i) CHECK(from_bag[i] == from_folder[i]);
}

// ROS 1 bags (rosbag:FILE), written by ROS 1's own Python writer (python3-rosbag).

namespace {

std::unique_ptr<BagSource> open_rosbag(const std::string& path, const char* query = "") {
  return open_bag(path, query, "rosbag:");
}

}  // namespace

TEST_CASE("rosbag: sim frames come back the same in every compression and layout",
          "[replay][bag][rosbag]") {
  Fixture fixture(sim_frames());
  struct Variant {
    const char* options;
    const char* depth_topic;
    int units_ratio;
    bool poses;
  };
  const Variant variants[] = {
      {"--compression none", "/camera/depth/image_raw", 1, true},
      {"--compression bz2", "/camera/depth/image_raw", 1, true},
      {"--compression lz4", "/camera/depth/image_raw", 1, true},
      // A chunk per message, as a bag of large images is.
      {"--compression bz2 --chunk-threshold 1", "/camera/depth/image_raw", 1, true},
      {"--compression none --chunk-threshold 1 --pose odometry", "/camera/depth/image_raw", 1,
       true},
      {"--compression lz4 --pose pose_stamped --encoding mono16", "/camera/depth/image_raw", 1,
       true},
      {"--compression none --pose none", "/camera/depth/image_raw", 1, false},
      {"--compression bz2 --encoding 32FC1", "/camera/depth/image_raw", 5, true},
      // TUM RGB-D's layout: 32FC1 on /camera/depth/image, a colour image, two camera infos, an
      // IMU, tf/tfMessage with leading-slash frames chained down to the optical frame.
      {"--compression bz2 --tum", "/camera/depth/image", 5, true},
  };
  std::vector<std::pair<std::string, std::string>> jobs;
  for (const Variant& v : variants)
    jobs.push_back({"v" + std::to_string(jobs.size()) + ".bag", v.options});
  const std::vector<std::string> paths = fixture.rosbags(jobs);
  for (std::size_t n = 0; n < paths.size(); ++n) {
    const Variant& v = variants[n];
    const std::string& path = paths[n];
    INFO(v.options);
    std::unique_ptr<BagSource> bag = open_rosbag(path);
    {
      const octofuse::Status opened = bag->open();
      INFO(bag->last_error());
      REQUIRE(opened.ok());
    }
    CHECK(std::strcmp(bag->depth_topic(), v.depth_topic) == 0);
    check_same_frames(*bag, fixture.kept, v.units_ratio, v.poses);
    CHECK(bag->frames_without_pose() == 0);
  }
}

TEST_CASE("rosbag: the same frames as the MCAP bag of them, bit for bit", "[replay][bag][rosbag]") {
  Fixture fixture(sim_frames());
  const std::string mcap = fixture.bag("same.mcap", "--compression none");
  const std::string ros1 = fixture.rosbag("same.bag", "--compression bz2");
  if (ros1.empty()) return;
  std::unique_ptr<BagSource> a = open_bag(mcap);
  std::unique_ptr<BagSource> b = open_rosbag(ros1);
  REQUIRE(a->open().ok());
  REQUIRE(b->open().ok());
  const KeptFrames from_mcap = keep_frames(*a, 100);
  const KeptFrames from_ros1 = keep_frames(*b, 100);
  REQUIRE(from_mcap.frames.size() == static_cast<std::size_t>(kSimFrames));
  REQUIRE(from_ros1.frames.size() == from_mcap.frames.size());
  for (std::size_t i = 0; i < from_mcap.frames.size(); ++i) {
    CHECK(from_ros1.frames[i].depth == from_mcap.frames[i].depth);
    CHECK(from_ros1.frames[i].timestamp_us == from_mcap.frames[i].timestamp_us);
    CHECK(from_ros1.frames[i].metres_per_unit == from_mcap.frames[i].metres_per_unit);
    CHECK(from_ros1.frames[i].T_W_C == from_mcap.frames[i].T_W_C);
  }
}

TEST_CASE("rosbag: a bag of sim frames gives the same trajectory as the sim",
          "[replay][bag][rosbag]") {
  Fixture fixture(sim_frames());
  const std::string path = fixture.rosbag("same.bag", "--compression lz4");
  if (path.empty()) return;
  octofuse::sim::SimSource sim(small_sim(kSimFrames));
  REQUIRE(sim.open().ok());
  std::unique_ptr<BagSource> bag = open_rosbag(path);
  REQUIRE(bag->open().ok());
  const Eigen::Matrix4d first = fixture.kept.frames[0].T_W_C;
  const std::vector<Eigen::Matrix4d> from_sim = track(sim, sim.intrinsics(), first);
  const std::vector<Eigen::Matrix4d> from_bag = track(*bag, bag->intrinsics(), first);
  REQUIRE(from_sim.size() == static_cast<std::size_t>(kSimFrames));
  REQUIRE(from_bag.size() == from_sim.size());
  for (std::size_t i = 0; i < from_sim.size(); ++i) CHECK(from_bag[i] == from_sim[i]);
}

TEST_CASE("rosbag: next() after open() does not allocate", "[replay][bag][rosbag]") {
  if (!octofuse::test::counts_malloc()) return;  // the sanitizers own malloc
  Fixture fixture(sim_frames());
  for (const std::string& path :
       fixture.rosbags({{"a0.bag", "--compression none"},
                        {"a1.bag", "--compression bz2"},
                        {"a2.bag", "--compression lz4"},
                        {"a3.bag", "--compression bz2 --chunk-threshold 1"}})) {
    INFO(path);
    std::unique_ptr<BagSource> bag = open_rosbag(path);
    REQUIRE(bag->open().ok());
    octofuse::DepthFrame frame;
    int frames = 0;
    octofuse::test::AllocationScope scope;
    while (bag->next(frame).outcome == FrameOutcome::frame) ++frames;
    CHECK(scope.allocations() == 0);
    CHECK(frames == kSimFrames);
  }
}

namespace {

// Everything a RosbagReader gives out, and how it ends.
struct ReadOut {
  std::vector<std::string> messages;  // topic, log time and bytes of each
  octofuse::replay::McapNext last = octofuse::replay::McapNext::message;
  std::string error;
  std::string warning;
  std::uint64_t read_ahead = 0;
  std::size_t reserved = 0;
};

ReadOut read_all(const std::string& path, bool read_ahead, int rewind_after = -1) {
  octofuse::replay::RosbagReader reader;
  octofuse::replay::McapLimits limits;
  limits.read_ahead = read_ahead;
  ReadOut out;
  if (!reader.open(path.c_str(), limits).ok()) {
    out.last = octofuse::replay::McapNext::error;
    out.error = reader.error();
    return out;
  }
  octofuse::replay::McapMessage message;
  int count = 0;
  for (;;) {
    out.last = reader.next(&message);
    if (out.last != octofuse::replay::McapNext::message) break;
    if (count++ == rewind_after) {  // part of the way, then from the start again
      reader.rewind();
      out.messages.clear();
      continue;
    }
    out.messages.push_back(std::string(message.channel->topic) + " " +
                           std::to_string(message.log_time_ns) + " " +
                           std::string(reinterpret_cast<const char*>(message.data), message.size));
  }
  out.error = reader.error();
  out.warning = reader.warning();
  out.read_ahead = reader.chunks_read_ahead();
  out.reserved = reader.bytes_reserved();
  return out;
}

}  // namespace

TEST_CASE("rosbag: read-ahead gives the same messages, errors and warnings as reading alone",
          "[replay][bag][rosbag]") {
  Fixture fixture(sim_frames());
  const std::vector<std::string> bags =
      fixture.rosbags({{"r0.bag", "--compression bz2 --chunk-threshold 1"},
                       {"r1.bag", "--compression lz4 --chunk-threshold 1"},
                       {"r2.bag", "--compression bz2 --tum --chunk-threshold 1"},
                       {"r3.bag", "--compression none --chunk-threshold 1"}});
  if (bags.empty()) return;
  std::vector<std::string> cases = bags;
  // Damaged copies of the chunk-per-message bz2 bag: a chunk's data corrupt in the middle of the
  // file, the file cut inside a later chunk, a chunk record's length past the end.
  const std::string bytes = read_bytes(bags[0]);
  std::string corrupt = bytes;
  for (std::size_t i = bytes.size() / 2; i < bytes.size() / 2 + 64; ++i) corrupt[i] = 'x';
  cases.push_back(fixture.dir + "/r-corrupt.bag");
  write_text(cases.back(), corrupt);
  cases.push_back(fixture.dir + "/r-cut.bag");
  write_text(cases.back(), bytes.substr(0, bytes.size() * 2 / 3));
  cases.push_back(fixture.dir + "/r-cut-late.bag");
  write_text(cases.back(), bytes.substr(0, bytes.size() - 100));
  for (std::size_t n = 0; n < cases.size(); ++n) {
    INFO(cases[n]);
    const ReadOut alone = read_all(cases[n], false);
    const ReadOut ahead = read_all(cases[n], true);
    CHECK(alone.read_ahead == 0);
    CHECK(ahead.messages.size() == alone.messages.size());
    CHECK(ahead.messages == alone.messages);
    CHECK(ahead.last == alone.last);
    CHECK(ahead.error == alone.error);
    CHECK(ahead.warning == alone.warning);
    if (n < 3) {
      // Compressed and whole: every chunk after the first comes from the worker.
      CHECK(alone.last == octofuse::replay::McapNext::end);
      CHECK(alone.messages.size() >= 15);
      CHECK(ahead.read_ahead > 0);
    }
    // Read-ahead's memory only for a compressed bag: none for the uncompressed one.
    const octofuse::replay::McapLimits limits;
    const std::size_t base = octofuse::replay::RosbagReader::bytes_required(limits);
    CHECK(alone.reserved == base);
    CHECK(ahead.reserved ==
          base + (n == 3 ? 0 : octofuse::replay::RosbagReader::read_ahead_bytes(limits)));
    if (n == 3) CHECK(ahead.read_ahead == 0);  // uncompressed: nothing for the worker
    // A rewind part of the way drops what the worker holds: the same messages again.
    const ReadOut rewound = read_all(cases[n], true, 7);
    CHECK(rewound.messages == alone.messages);
    CHECK(rewound.last == alone.last);
  }
  CHECK(read_all(cases[4], true).last == octofuse::replay::McapNext::error);
  CHECK(read_all(cases[5], true).last == octofuse::replay::McapNext::truncated);
}

namespace {

// What a BagReader gives out, each message as topic, log time and data size (its size in the
// file when skimmed); with `skim_topic` non-null, skimming every chunk that holds no message on
// that topic ("" : none wanted).
struct SkimOut {
  std::vector<std::string> messages;
  octofuse::replay::McapNext last = octofuse::replay::McapNext::message;
  std::string warning;
  std::uint64_t out_of_order = 0;
  std::uint64_t skimmed = 0;
  int with_data = 0;  // messages given with their bytes
  bool wanted_data_given = true;
};

bool wants_topic(void* topic, const octofuse::replay::McapChannel& channel) {
  return std::strcmp(channel.topic, static_cast<const char*>(topic)) == 0;
}

SkimOut read_skimming(const std::string& path, const char* skim_topic, std::size_t window_bytes) {
  octofuse::replay::McapLimits limits;
  limits.reorder_bytes = window_bytes;
  octofuse::replay::BagReader reader;
  SkimOut out;
  REQUIRE(reader.open(path.c_str(), octofuse::replay::BagFormat::rosbag, limits).ok());
  if (skim_topic != nullptr) reader.set_skim(wants_topic, const_cast<char*>(skim_topic));
  octofuse::replay::McapMessage message;
  while ((out.last = reader.next(&message)) == octofuse::replay::McapNext::message) {
    const std::size_t size = message.data != nullptr ? message.size : message.skimmed_size;
    out.messages.push_back(std::string(message.channel->topic) + " " +
                           std::to_string(message.log_time_ns) + " " + std::to_string(size));
    if (message.data != nullptr) ++out.with_data;
    if (skim_topic != nullptr && std::strcmp(message.channel->topic, skim_topic) == 0 &&
        message.data == nullptr) {
      out.wanted_data_given = false;
    }
  }
  out.warning = reader.warning();
  out.out_of_order = reader.out_of_order();
  out.skimmed = reader.chunks_skimmed();
  return out;
}

}  // namespace

TEST_CASE("rosbag: skimming chunks by their index gives the same messages, order and warnings",
          "[replay][bag][rosbag]") {
  Fixture fixture(sim_frames());
  const std::vector<std::string> bags =
      fixture.rosbags({{"s0.bag", "--compression bz2 --tum --chunk-threshold 1"},
                       {"s1.bag", "--compression none --overlap --chunk-threshold 1"},
                       {"s2.bag", "--compression lz4 --chunk-threshold 1"},
                       {"s3.bag", "--compression bz2"}});
  if (bags.empty()) return;
  std::vector<std::string> cases = bags;
  // Cut copies: inside the last chunk's index records, and inside a chunk half-way.
  const std::string bytes = read_bytes(bags[0]);
  for (const std::size_t cut : {bytes.size() - 40, bytes.size() / 2}) {
    cases.push_back(fixture.dir + "/s-cut" + std::to_string(cut) + ".bag");
    write_text(cases.back(), bytes.substr(0, cut));
  }
  for (std::size_t n = 0; n < cases.size(); ++n) {
    for (const std::size_t window : {std::size_t{8} << 20, std::size_t{0}, std::size_t{64}}) {
      INFO(cases[n] << " window " << window);
      const SkimOut read = read_skimming(cases[n], nullptr, window);
      const SkimOut skim = read_skimming(cases[n], "", window);
      CHECK(read.skimmed == 0);
      CHECK(skim.messages == read.messages);  // same topics, times, sizes and order
      CHECK(skim.last == read.last);
      CHECK(skim.warning == read.warning);
      CHECK(skim.out_of_order == read.out_of_order);
      CHECK(read.with_data == static_cast<int>(read.messages.size()));
      if (n == 0 || n == 1 || n == 2) {
        // Closed, a chunk per message: all but the chunks declaring a connection are skimmed.
        CHECK(skim.skimmed > 0);
        CHECK(skim.with_data < static_cast<int>(skim.messages.size()) / 2);
      }
      if (n == 3) CHECK(skim.skimmed == 0);  // one chunk, declaring every connection
      // Wanting one topic: its messages all come with their bytes.
      const SkimOut depth = read_skimming(cases[n], "/camera/depth/image", window);
      CHECK(depth.messages == read.messages);
      CHECK(depth.wanted_data_given);
    }
  }
}

TEST_CASE("rosbag: a bag's odometry poses for the prior", "[replay][bag][rosbag]") {
  Fixture fixture(sim_frames());
  std::vector<Eigen::Matrix4d> poses;
  auto collect = [](void* context, std::int64_t, const octofuse::Se3d& T) {
    static_cast<std::vector<Eigen::Matrix4d>*>(context)->push_back(T.matrix());
  };
  const std::string path = fixture.rosbag("odom.bag", "--compression bz2 --pose odometry");
  if (path.empty()) return;
  BagConfig config;
  octofuse::ErrorText error;
  REQUIRE(octofuse::replay::parse_bag_spec(("rosbag:" + path).c_str(), &config, &error).ok());
  REQUIRE(octofuse::replay::read_bag_poses(config, collect, &poses, &error).ok());
  REQUIRE(poses.size() == fixture.kept.frames.size());
  for (std::size_t i = 0; i < poses.size(); ++i) {
    CHECK((poses[i] - fixture.kept.frames[i].T_W_C).cwiseAbs().maxCoeff() < 1e-12);
  }
}

TEST_CASE("rosbag: a bag cut at any byte replays to its last whole message",
          "[replay][bag][rosbag]") {
  Fixture fixture(sim_frames());
  // A compressed chunk is a compressed stream: cut inside it, what its last whole compressed
  // block holds is read (bzip2's blocks are up to 900 kB, so often nothing). With a chunk per
  // message (as images larger than the chunk threshold are) or uncompressed chunks, a cut loses
  // only the message it went through.
  struct Variant {
    const char* options;
    bool to_last_message;
  };
  const Variant variants[] = {{"--compression none", true},
                              {"--compression bz2", false},
                              {"--compression lz4", false},
                              {"--compression lz4 --chunk-threshold 1", true},
                              {"--compression bz2 --chunk-threshold 1", true},
                              {"--compression none --chunk-threshold 1", true}};
  std::vector<std::pair<std::string, std::string>> jobs;
  for (const Variant& v : variants)
    jobs.push_back({"w" + std::to_string(jobs.size()) + ".bag", v.options});
  const std::vector<std::string> paths = fixture.rosbags(jobs);
  for (std::size_t n = 0; n < paths.size(); ++n) {
    const Variant& v = variants[n];
    const std::string& whole = paths[n];
    INFO(v.options);
    const std::string bytes = read_bytes(whole);
    const std::string cut = fixture.dir + "/cut.bag";
    std::size_t previous_frames = 0;
    int cuts = 0;
    for (std::size_t size = 0; size < bytes.size(); size += 1 + size / 8, ++cuts) {
      INFO("cut at " << size);
      write_text(cut, bytes.substr(0, size));
      std::unique_ptr<BagSource> bag = open_rosbag(cut);
      const octofuse::Status opened = bag->open();
      if (!opened.ok()) {
        // Cut before a whole camera info and image: one clear error, and no frame later on.
        CHECK(std::strlen(bag->last_error()) > 0);
        CHECK(previous_frames == 0);
        continue;
      }
      octofuse::DepthFrame frame;
      std::size_t frames = 0;
      NextFrame next;
      while ((next = bag->next(frame)).outcome == FrameOutcome::frame) {
        const KeptFrame& k = fixture.kept.frames.at(frames);
        CHECK(frame.timestamp_us == k.timestamp_us);
        CHECK(std::memcmp(frame.depth_raw.data, k.depth.data(), k.depth.size() * 2) == 0);
        ++frames;
      }
      CHECK(next.outcome == FrameOutcome::end_of_stream);
      if (next.status.code() == StatusCode::end_of_stream) {
        // Cut in the index section: every message was read.
        CHECK(frames == fixture.kept.frames.size());
      } else {
        CHECK(next.status.code() == StatusCode::data_loss);
        CHECK(std::strstr(bag->last_error(), "cut short at byte") != nullptr);
      }
      CHECK(frames >= previous_frames);
      previous_frames = frames;
    }
    CHECK(cuts > 40);
    if (v.to_last_message) CHECK(previous_frames + 1 >= fixture.kept.frames.size());
  }
}

namespace {

// A bag as a killed recorder leaves it: the bag header's index position 0, the last chunk's
// sizes never written (0, as rosbag writes them first), the file ending with that chunk's data.
std::string as_never_closed(std::string bytes) {
  auto le32 = [&](std::size_t at) {
    std::uint32_t v = 0;
    std::memcpy(&v, bytes.data() + at, 4);
    return v;
  };
  // The value of field `name` in the record header at `header` (`size` bytes); npos if none.
  auto field = [&](std::size_t header, std::uint32_t size, const std::string& name) {
    for (std::size_t pos = header; pos + 4 <= header + size;) {
      const std::uint32_t n = le32(pos);
      if (bytes.compare(pos + 4, name.size() + 1, name + "=") == 0) {
        return pos + 4 + name.size() + 1;
      }
      pos += 4 + n;
    }
    return std::string::npos;
  };
  const std::size_t index_pos = field(17, le32(13), "index_pos");
  REQUIRE(index_pos != std::string::npos);
  std::memset(&bytes[index_pos], 0, 8);
  std::size_t last_chunk = 0;
  for (std::size_t pos = 13; pos + 8 <= bytes.size();) {
    const std::uint32_t header = le32(pos);
    if (bytes[field(pos + 4, header, "op")] == 0x05) last_chunk = pos;
    pos += 8 + header + le32(pos + 4 + header);
  }
  REQUIRE(last_chunk > 0);
  const std::uint32_t header = le32(last_chunk);
  const std::size_t end = last_chunk + 8 + header + le32(last_chunk + 4 + header);
  const std::size_t size = field(last_chunk + 4, header, "size");
  REQUIRE(size != std::string::npos);
  std::memset(&bytes[size], 0, 4);
  std::memset(&bytes[last_chunk + 4 + header], 0, 4);
  return bytes.substr(0, end);
}

}  // namespace

TEST_CASE("rosbag: a bag its recorder never closed replays with a warning",
          "[replay][bag][rosbag]") {
  Fixture fixture(sim_frames());
  const char* options[] = {"--compression none", "--compression bz2", "--compression lz4",
                           "--compression lz4 --chunk-threshold 1"};
  std::vector<std::pair<std::string, std::string>> jobs;
  for (const char* o : options) jobs.push_back({"u" + std::to_string(jobs.size()) + ".bag", o});
  const std::vector<std::string> paths = fixture.rosbags(jobs);
  for (std::size_t n = 0; n < paths.size(); ++n) {
    INFO(options[n]);
    const std::string path = fixture.dir + "/unclosed.bag";
    write_text(path, as_never_closed(read_bytes(paths[n])));
    std::unique_ptr<BagSource> bag = open_rosbag(path);
    {
      const octofuse::Status opened = bag->open();
      INFO(bag->last_error());
      REQUIRE(opened.ok());
    }
    octofuse::DepthFrame frame;
    std::size_t frames = 0;
    NextFrame next;
    while ((next = bag->next(frame)).outcome == FrameOutcome::frame) {
      const KeptFrame& k = fixture.kept.frames.at(frames);
      CHECK(std::memcmp(frame.depth_raw.data, k.depth.data(), k.depth.size() * 2) == 0);
      ++frames;
    }
    CHECK(frames == fixture.kept.frames.size());
    CHECK(next.status.code() == StatusCode::data_loss);
    CHECK(std::strstr(bag->last_error(), "the recorder did not close the bag") != nullptr);
  }
}

TEST_CASE("rosbag: bad input gets one clear error", "[replay][bag][rosbag]") {
  Fixture fixture(sim_frames());
  // One run of the writer for every case (sections would run it again each).
  const std::vector<std::string> bags = fixture.rosbags(
      {{"good.bag", "--compression none --chunk-threshold 1"}, {"bz.bag", "--compression bz2"}});
  if (bags.empty()) return;
  const std::string& good = bags[0];
  const std::string bytes = read_bytes(good);
  {  // not a bag
    const std::string path = fixture.dir + "/x.bag";
    write_text(path, "not a bag at all");
    std::unique_ptr<BagSource> bag = open_rosbag(path);
    CHECK(bag->open().code() == StatusCode::data_loss);
    CHECK(std::strstr(bag->last_error(), "not a ROS 1 bag") != nullptr);
  }
  {  // an MCAP file given as rosbag:
    const std::string path = fixture.bag("m.mcap", "--compression none");
    std::unique_ptr<BagSource> bag = open_rosbag(path);
    CHECK(bag->open().code() == StatusCode::data_loss);
    CHECK(std::strstr(bag->last_error(), "not a ROS 1 bag") != nullptr);
  }
  {  // another format version
    const std::string path = fixture.dir + "/v12.bag";
    write_text(path, "#ROSBAG V1.2\n" + bytes.substr(13));
    std::unique_ptr<BagSource> bag = open_rosbag(path);
    CHECK(bag->open().code() == StatusCode::data_loss);
    CHECK(std::strstr(bag->last_error(), "format '1.2' is not supported") != nullptr);
  }
  {  // a missing file
    std::unique_ptr<BagSource> bag = open_rosbag(fixture.dir + "/none.bag");
    CHECK(bag->open().code() == StatusCode::unavailable);
  }
  {  // a depth topic that is not there
    std::unique_ptr<BagSource> bag = open_rosbag(good, "?depth=/nope");
    CHECK(bag->open().code() == StatusCode::invalid_argument);
    CHECK(std::strstr(bag->last_error(), "rosbag: no sensor_msgs/msg/Image") != nullptr);
    CHECK(std::strstr(bag->last_error(), "/nope") != nullptr);
  }
  {  // a chunk larger than the buffer: the error says how to raise it
    const std::string& path = bags[1];
    octofuse::replay::RosbagReader reader;
    octofuse::replay::McapLimits limits;
    limits.max_chunk_bytes = 4096;  // a 160 x 120 frame alone is 38 kB
    REQUIRE(reader.open(path.c_str(), limits).ok());
    octofuse::replay::McapMessage message;
    octofuse::replay::McapNext got;
    while ((got = reader.next(&message)) == octofuse::replay::McapNext::message) {
    }
    CHECK(got == octofuse::replay::McapNext::error);
    CHECK(std::strstr(reader.error(), "raise it with ?buffer=MB") != nullptr);
  }
  {  // corrupt bz2 data
    std::string corrupt = read_bytes(bags[1]);
    for (std::size_t i = 5000; i < 5100 && i < corrupt.size(); ++i) corrupt[i] = 'x';
    const std::string path = fixture.dir + "/corrupt.bag";
    write_text(path, corrupt);
    std::unique_ptr<BagSource> bag = open_rosbag(path);
    CHECK(bag->open().code() == StatusCode::data_loss);
    CHECK(std::strstr(bag->last_error(), "corrupt bz2 data") != nullptr);
  }
  {  // every record's header or data length flipped: an error or a warning, never a crash
    // Record boundaries, found as the reader would: magic, bag header, then chunks whose
    // records are loose (uncompressed).
    auto le32 = [&](std::size_t at) {
      std::uint32_t v = 0;
      std::memcpy(&v, bytes.data() + at, 4);
      return v;
    };
    std::vector<std::size_t> length_fields;
    std::size_t pos = 13;
    while (pos + 8 <= bytes.size()) {
      const std::uint32_t header = le32(pos);
      length_fields.push_back(pos);
      length_fields.push_back(pos + 4 + header);
      const std::uint32_t data = le32(pos + 4 + header);
      const bool chunk = bytes.find(std::string("op=\x05", 4), pos + 4) < pos + 4 + header;
      pos += 8 + header + (chunk ? 0 : data);  // into a chunk's records
    }
    REQUIRE(length_fields.size() > 20);
    const std::string path = fixture.dir + "/flipped.bag";
    int errors = 0, warnings = 0;
    for (const std::size_t at : length_fields) {
      for (const std::uint8_t flip : {0x01, 0x80}) {
        std::string changed = bytes;
        changed[at + (flip == 0x80 ? 3 : 0)] ^= static_cast<char>(flip);
        write_text(path, changed);
        std::unique_ptr<BagSource> bag = open_rosbag(path);
        if (!bag->open().ok()) {
          CHECK(std::strlen(bag->last_error()) > 0);
          ++errors;
          continue;
        }
        octofuse::DepthFrame frame;
        NextFrame next;
        int frames = 0;
        while ((next = bag->next(frame)).outcome != FrameOutcome::end_of_stream &&
               next.outcome != FrameOutcome::error && frames < 100) {
          frames += next.outcome == FrameOutcome::frame;
          if (next.outcome == FrameOutcome::skip) CHECK(std::strlen(bag->last_error()) > 0);
        }
        CHECK(frames <= kSimFrames);
        if (next.status.code() != StatusCode::end_of_stream) {
          CHECK(std::strlen(bag->last_error()) > 0);
          ++warnings;
        }
      }
    }
    CHECK(errors + warnings > 0);
  }
  {  // spec
    BagConfig config;
    octofuse::ErrorText error;
    REQUIRE(
        octofuse::replay::parse_bag_spec("rosbag:a.bag?depth=/d&buffer=2", &config, &error).ok());
    CHECK(config.format == octofuse::replay::BagFormat::rosbag);
    CHECK(std::strcmp(config.path, "a.bag") == 0);
    CHECK(std::strcmp(config.depth_topic, "/d") == 0);
    CHECK(octofuse::replay::parse_bag_spec("rosbag:", &config, &error).code() ==
          StatusCode::invalid_argument);
    CHECK(std::strstr(error.c_str(), "rosbag: needs a file") != nullptr);
    CHECK(octofuse::replay::parse_bag_spec("bag:x", &config, &error).code() ==
          StatusCode::invalid_argument);
  }
}

TEST_CASE("rosbag: a bag of 7-Scenes frames gives their trajectory",
          "[replay][bag][rosbag][data]") {
  std::string why;
  const std::string recording = octofuse::test::recording_dir("7scenes-redkitchen", &why);
  if (recording.empty()) {
    WARN(why << ": skipping the 7-Scenes ROS 1 bag test");
    return;
  }
  constexpr int kFrames = 4;
  const std::string spec = "7scenes:" + recording;
  octofuse::replay::ReplayConfig config;
  octofuse::ErrorText error;
  REQUIRE(octofuse::replay::parse_replay_spec(spec.c_str(), &config, &error).ok());
  octofuse::replay::ReplaySource seven(config);
  REQUIRE(seven.open().ok());
  Fixture fixture(keep_frames(seven, kFrames));
  const std::string path = fixture.rosbag("7scenes.bag", "--compression lz4");
  if (path.empty()) return;
  std::unique_ptr<BagSource> bag = open_rosbag(path);
  REQUIRE(bag->open().ok());
  // 7-Scenes' rotations are orthonormal to about 6e-5 only; a quaternion makes them exact.
  check_same_frames(*bag, fixture.kept, 1, true, 1e-4);

  octofuse::replay::ReplaySource again(config);
  REQUIRE(again.open().ok());
  std::unique_ptr<BagSource> bag_again = open_rosbag(path);
  REQUIRE(bag_again->open().ok());
  const Eigen::Matrix4d first = fixture.kept.frames[0].T_W_C;
  const std::vector<Eigen::Matrix4d> from_folder = track(again, again.intrinsics(), first, kFrames);
  const std::vector<Eigen::Matrix4d> from_bag = track(*bag_again, bag_again->intrinsics(), first);
  REQUIRE(from_bag.size() == from_folder.size());
  for (std::size_t i = 0; i < from_bag.size(); ++i) CHECK(from_bag[i] == from_folder[i]);
}

namespace {

// An unchunked MCAP of small messages on one channel with the given log times; message i's
// payload is its index (8 bytes) then `sizes[i] - 8` bytes of (i + j) & 0xFF.
void write_mcap_messages(const std::string& path, const std::vector<std::uint64_t>& log_ns,
                         const std::vector<std::size_t>& sizes) {
  std::string out("\x89MCAP0\r\n", 8);
  auto le = [&](std::uint64_t v, int bytes) {
    for (int i = 0; i < bytes; ++i) out.push_back(static_cast<char>(v >> (8 * i)));
  };
  auto str = [&](const std::string& s) {
    le(s.size(), 4);
    out += s;
  };
  out.push_back(0x04);  // channel 1, no schema, topic /n
  le(2 + 2 + 4 + 2 + 4 + 3 + 4, 8);
  le(1, 2);
  le(0, 2);
  str("/n");
  str("cdr");
  le(0, 4);
  for (std::size_t i = 0; i < log_ns.size(); ++i) {
    out.push_back(0x05);
    le(22 + sizes[i], 8);
    le(1, 2);
    le(i, 4);
    le(log_ns[i], 8);
    le(log_ns[i], 8);
    le(i, 8);
    for (std::size_t j = 8; j < sizes[i]; ++j) out.push_back(static_cast<char>((i + j) & 0xFF));
  }
  out.push_back(0x0F);
  le(4, 8);
  le(0, 4);
  out.push_back(0x02);
  le(20, 8);
  le(0, 8);
  le(0, 8);
  le(0, 4);
  out += std::string("\x89MCAP0\r\n", 8);
  write_text(path, out);
}

}  // namespace

TEST_CASE("bag: the reorder window sorts what it can reach and counts the rest", "[replay][bag]") {
  // 2000 messages of 8 B to 3 kB, each logged up to `shift` places from its place in the file;
  // windows from 4 kB (less than two messages) to 1 MB (all), rings that wrap many times.
  const std::string dir = make_test_dir("reorder");
  const std::string path = dir + "/shuffled.mcap";
  std::uint64_t seed = 12345;
  auto random = [&](std::uint64_t n) {
    seed = seed * 6364136223846793005ull + 1442695040888963407ull;
    return (seed >> 33) % n;
  };
  const int count = 2000;
  for (const int shift : {0, 3, 40}) {
    std::vector<std::uint64_t> log_ns;
    std::vector<std::size_t> sizes;
    for (int i = 0; i < count; ++i) {
      log_ns.push_back(1000 * static_cast<std::uint64_t>(i + 1 + random(shift + 1)));
      sizes.push_back(8 + random(3000));
    }
    write_mcap_messages(path, log_ns, sizes);
    for (const std::size_t window :
         {std::size_t{4096}, std::size_t{64} << 10, std::size_t{1} << 20}) {
      for (const int slots : {16, 4096}) {
        INFO("shift " << shift << ", window " << window << " bytes, " << slots << " messages");
        octofuse::replay::McapLimits limits;
        limits.reorder_bytes = window;
        limits.reorder_messages = slots;
        octofuse::replay::BagReader reader;
        REQUIRE(reader.open(path.c_str(), octofuse::replay::BagFormat::mcap, limits).ok());
        std::vector<int> seen(count, 0);
        octofuse::replay::McapMessage message;
        std::uint64_t last_ns = 0;
        std::uint64_t backwards = 0;
        int corrupt = 0;
        octofuse::replay::McapNext got;
        while ((got = reader.next(&message)) == octofuse::replay::McapNext::message) {
          std::uint64_t index = 0;
          std::memcpy(&index, message.data, 8);
          REQUIRE(index < static_cast<std::uint64_t>(count));
          ++seen[index];
          corrupt += message.size != sizes[index] || message.log_time_ns != log_ns[index];
          for (std::size_t j = 8; j < message.size; ++j) {
            corrupt += message.data[j] != static_cast<std::uint8_t>((index + j) & 0xFF);
          }
          if (message.log_time_ns < last_ns) {
            ++backwards;
          } else {
            last_ns = message.log_time_ns;
          }
        }
        CHECK(got == octofuse::replay::McapNext::end);
        CHECK(corrupt == 0);
        CHECK(std::count(seen.begin(), seen.end(), 1) == count);  // each once
        CHECK(backwards == reader.out_of_order());
        // A window that holds the displacement (40 places of up to 3 kB) puts all in order.
        if (shift == 0 || (window == (std::size_t{1} << 20) && slots == 4096)) {
          CHECK(backwards == 0);
        }
        if (shift == 40 && window == 4096) CHECK(backwards > 0);
      }
    }
  }
}
