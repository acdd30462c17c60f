// The MCAP bag reader against bags an independent writer (make_bag.py) made from sim and
// 7-Scenes frames: the same pixels, timestamps, intrinsics and poses, the same trajectory, every
// compression and layout, cuts at any byte, and bad input answered with one clear error.

#include <catch2/catch.hpp>
#include <cmath>
#include <cstring>
#include <memory>
#include <string>

#include "bag_fixtures.hpp"
#include "octofuse/pipeline/mapper.hpp"
#include "octofuse/ports/replay/bag_source.hpp"
#include "octofuse/ports/replay/replay_source.hpp"
#include "octofuse/ports/sim/sim_source.hpp"
#include "support/alloc_counter.hpp"
#include "support/small_sim.hpp"
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

std::unique_ptr<BagSource> open_bag(const std::string& path, const char* query = "") {
  BagConfig config;
  octofuse::ErrorText error;
  const std::string spec = "mcap:" + path + query;
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

struct Fixture {
  std::string dir = make_test_dir("bag");
  std::string dump = dir + "/frames.bin";
  KeptFrames kept;
  explicit Fixture(KeptFrames frames) : kept(std::move(frames)) { write_frame_dump(dump, kept); }
  // The bag's path, or empty when the writer lacks a compression module (the case skips).
  std::string bag(const std::string& name, const std::string& options) {
    const std::string path = dir + "/" + name;
    const int rc = make_bag(dump, path, options);
    if (rc == 77) {
      WARN("make_bag.py " << options << ": python module missing, case skipped");
      return std::string();
    }
    REQUIRE(rc == 0);
    return path;
  }
};

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
    CHECK(octofuse::replay::parse_bag_spec("mcap:", &config, &error).code() ==
          StatusCode::invalid_argument);
    CHECK(octofuse::replay::parse_bag_spec("mcap:a?colour=x", &config, &error).code() ==
          StatusCode::invalid_argument);
    CHECK(octofuse::replay::parse_bag_spec("mcap:a?depth=", &config, &error).code() ==
          StatusCode::invalid_argument);
  }
}

TEST_CASE("mcap: a bag of 7-Scenes frames gives their trajectory", "[replay][bag][data]") {
  const char* data_dir = std::getenv("OCTOFUSE_TEST_DATA_DIR");
  if (data_dir == nullptr || data_dir[0] == '\0') {
    WARN("OCTOFUSE_TEST_DATA_DIR is not set: skipping the 7-Scenes bag test");
    return;
  }
  constexpr int kFrames = 4;
  const std::string spec = std::string("7scenes:") + data_dir + "/7scenes-redkitchen";
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
