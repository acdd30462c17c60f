// Every kind of bad input a recorded dataset can have: each gives a Status and a message naming
// the file and the problem; a bad frame is skipped and the replay still ends cleanly.
#include <catch2/catch.hpp>
#include <string>

#include "fixtures.hpp"
#include "octofuse/ports/replay/replay_source.hpp"
#include "support/text.hpp"

using octofuse::DepthFrame;
using octofuse::FrameOutcome;
using octofuse::NextFrame;
using octofuse::StatusCode;
using octofuse::replay::ReplayConfig;
using octofuse::replay::ReplaySource;
using octofuse::test::contains;
namespace fx = octofuse::test;

namespace {

ReplayConfig config_for(const std::string& spec) {
  ReplayConfig config;
  octofuse::ErrorText error;
  REQUIRE(octofuse::replay::parse_replay_spec(spec.c_str(), &config, &error).ok());
  config.has_intrinsics = spec.rfind("raw:", 0) == 0;
  config.intrinsics = octofuse::PinholeCamera{500.0f, 500.0f, 3.0f, 2.0f, 0, 0};
  return config;
}

// Reads to the end; returns the sequence numbers delivered and the skip messages.
struct Replayed {
  std::vector<std::uint64_t> frames;
  std::vector<std::string> skips;
  std::vector<StatusCode> skip_codes;
  bool ended = false;
};
Replayed replay_all(ReplaySource& source) {
  Replayed out;
  for (int guard = 0; guard < 1000; ++guard) {
    DepthFrame frame;
    const NextFrame got = source.next(frame);
    if (got.outcome == FrameOutcome::frame) {
      out.frames.push_back(frame.sequence);
    } else if (got.outcome == FrameOutcome::skip) {
      out.skips.push_back(source.last_error());
      out.skip_codes.push_back(got.status.code());
    } else {
      out.ended = got.outcome == FrameOutcome::end_of_stream;
      break;
    }
  }
  return out;
}

std::string frame_png(const fx::TumFixture& tum, int i) {
  char name[64];
  std::snprintf(name, sizeof(name), "/depth/%.6f.png", tum.timestamps[static_cast<std::size_t>(i)]);
  return tum.dir + name;
}

}  // namespace

TEST_CASE("a folder that does not exist", "[replay][bad]") {
  for (const char* prefix : {"tum:", "icl:", "7scenes:", "raw:"}) {
    const std::string path = "/nonexistent/octofuse-dataset";
    ReplaySource source(config_for(prefix + path));
    CHECK(source.open() == StatusCode::unavailable);
    CHECK(contains(source.last_error(), path));
    DepthFrame frame;
    const NextFrame got = source.next(frame);
    CHECK(got.outcome == FrameOutcome::error);
    CHECK(got.status == StatusCode::failed_precondition);
  }
}

TEST_CASE("missing or unparsable text files", "[replay][bad]") {
  const std::string parent = fx::make_test_dir("bad-text");

  SECTION("depth.txt missing") {
    const fx::TumFixture tum = fx::write_tum(parent, "nolist");
    std::remove((tum.dir + "/depth.txt").c_str());
    ReplaySource source(config_for("tum:" + tum.dir));
    CHECK(source.open() == StatusCode::unavailable);
    CHECK(contains(source.last_error(), "depth.txt: cannot open"));
  }
  SECTION("depth.txt line without a file name") {
    const fx::TumFixture tum = fx::write_tum(parent, "badlist");
    fx::write_text(tum.dir + "/depth.txt", "# header\n1.0 depth/a.png\n2.0\n");
    ReplaySource source(config_for("tum:" + tum.dir));
    CHECK(source.open() == StatusCode::data_loss);
    CHECK(contains(source.last_error(), "depth.txt:3: expected a file name"));
  }
  SECTION("depth.txt with a non-number timestamp") {
    const fx::TumFixture tum = fx::write_tum(parent, "badtime");
    fx::write_text(tum.dir + "/depth.txt", "abc depth/a.png\n");
    ReplaySource source(config_for("tum:" + tum.dir));
    CHECK(source.open() == StatusCode::data_loss);
    CHECK(contains(source.last_error(), "depth.txt:1: expected a timestamp"));
  }
  SECTION("empty depth.txt") {
    const fx::TumFixture tum = fx::write_tum(parent, "empty");
    fx::write_text(tum.dir + "/depth.txt", "# nothing\n");
    ReplaySource source(config_for("tum:" + tum.dir));
    CHECK(source.open() == StatusCode::data_loss);
    CHECK(contains(source.last_error(), "lists no frames"));
  }
  SECTION("groundtruth.txt with a short line") {
    const fx::TumFixture tum = fx::write_tum(parent, "badgt");
    fx::write_text(tum.dir + "/groundtruth.txt", "1305031102.0 1 2 3 0 0 0\n");
    ReplaySource source(config_for("tum:" + tum.dir));
    CHECK(source.open() == StatusCode::data_loss);
    CHECK(contains(source.last_error(), "groundtruth.txt:1: expected 8 numbers"));
  }
  SECTION("camera-intrinsics.txt missing") {
    const std::string dir = fx::write_seven_scenes(parent);
    std::remove((dir + "/camera-intrinsics.txt").c_str());
    ReplaySource source(config_for("7scenes:" + dir));
    CHECK(source.open() == StatusCode::unavailable);
    CHECK(contains(source.last_error(), "camera-intrinsics.txt: cannot open"));
  }
  SECTION("camera-intrinsics.txt not a camera matrix") {
    const std::string dir = fx::write_seven_scenes(parent);
    fx::write_text(dir + "/camera-intrinsics.txt", "585 0 320\n0 585 240\n0 0\n");
    ReplaySource source(config_for("7scenes:" + dir));
    CHECK(source.open() == StatusCode::data_loss);
    CHECK(contains(source.last_error(), "camera-intrinsics.txt: expected 9 numbers"));
  }
  SECTION("raw without intrinsics") {
    const std::string path = parent + "/x.raw";
    fx::write_text(path, fx::raw_frame_bytes(4, 3, 0));
    ReplayConfig config = config_for("raw:" + path);
    config.has_intrinsics = false;
    ReplaySource source(config);
    CHECK(source.open() == StatusCode::invalid_argument);
    CHECK(contains(source.last_error(), "x.raw: a .raw recording has no intrinsics"));
  }
}

TEST_CASE("timestamps going backwards", "[replay][bad]") {
  const std::string parent = fx::make_test_dir("bad-time");
  SECTION("in depth.txt") {
    const fx::TumFixture tum = fx::write_tum(parent, "back");
    fx::write_text(tum.dir + "/depth.txt", "2.0 depth/a.png\n3.0 depth/b.png\n2.5 depth/c.png\n");
    ReplaySource source(config_for("tum:" + tum.dir));
    CHECK(source.open() == StatusCode::data_loss);
    CHECK(contains(source.last_error(), "depth.txt:3: timestamp 2.500000 goes backwards"));
  }
  SECTION("in groundtruth.txt") {
    const fx::TumFixture tum = fx::write_tum(parent, "gtback");
    fx::write_text(tum.dir + "/groundtruth.txt",
                   "1305031102.0 0 0 0 0 0 0 1\n1305031101.0 0 0 0 0 0 0 1\n");
    ReplaySource source(config_for("tum:" + tum.dir));
    CHECK(source.open() == StatusCode::data_loss);
    CHECK(contains(source.last_error(), "groundtruth.txt:2: timestamp"));
    CHECK(contains(source.last_error(), "goes backwards"));
  }
}

TEST_CASE("poses that are not rotations", "[replay][bad]") {
  const std::string parent = fx::make_test_dir("bad-pose");
  SECTION("TUM quaternion of length 2") {
    const fx::TumFixture tum = fx::write_tum(parent, "quat");
    fx::write_text(tum.dir + "/groundtruth.txt", "1305031102.0 0 0 0 0 0 0 2\n");
    ReplaySource source(config_for("tum:" + tum.dir));
    CHECK(source.open() == StatusCode::data_loss);
    CHECK(contains(source.last_error(), "groundtruth.txt:1: quaternion has length 2"));
  }
  SECTION("7-Scenes pose with a scaled rotation skips that frame only") {
    const std::string dir = fx::write_seven_scenes(parent, 3);
    Eigen::Matrix4d scaled = fx::pose_for_frame(1).matrix();
    scaled.topLeftCorner<3, 3>() *= 1.5;
    fx::write_text(dir + "/frame-000001.pose.txt", fx::matrix_text(scaled));
    ReplaySource source(config_for("7scenes:" + dir));
    REQUIRE(source.open().ok());
    const Replayed replayed = replay_all(source);
    CHECK(replayed.frames == std::vector<std::uint64_t>{0, 2});
    REQUIRE(replayed.skips.size() == 1);
    CHECK(contains(replayed.skips[0].c_str(), "frame-000001.pose.txt: not a rigid transform"));
    CHECK(replayed.ended);
  }
  SECTION("7-Scenes pose with too few numbers") {
    const std::string dir = fx::write_seven_scenes(parent, 2);
    fx::write_text(dir + "/frame-000001.pose.txt", "1 0 0 0\n0 1 0 0\n");
    ReplaySource source(config_for("7scenes:" + dir));
    REQUIRE(source.open().ok());
    const Replayed replayed = replay_all(source);
    CHECK(replayed.frames == std::vector<std::uint64_t>{0});
    REQUIRE(replayed.skips.size() == 1);
    CHECK(contains(replayed.skips[0].c_str(), "frame-000001.pose.txt: expected 16 numbers"));
  }
}

TEST_CASE("truncated, corrupt, missing and wrong-format PNG frames are skipped", "[replay][bad]") {
  const std::string parent = fx::make_test_dir("bad-png");
  const fx::TumFixture tum = fx::write_tum(parent, "png", 6);
  const std::string good = fx::read_bytes(frame_png(tum, 0));
  // 1: truncated in the middle of the image data.
  fx::write_text(frame_png(tum, 1), good.substr(0, good.size() / 2));
  // 2: one byte of the compressed data flipped (the chunk CRC no longer matches).
  std::string flipped = good;
  flipped[flipped.size() - 20] = static_cast<char>(flipped[flipped.size() - 20] ^ 0x55);
  fx::write_text(frame_png(tum, 2), flipped);
  // 3: not a PNG at all.
  fx::write_text(frame_png(tum, 3), "this is not a png");
  // 4: missing.
  std::remove(frame_png(tum, 4).c_str());
  ReplaySource source(config_for("tum:" + tum.dir));
  REQUIRE(source.open().ok());
  const Replayed replayed = replay_all(source);
  CHECK(replayed.frames == std::vector<std::uint64_t>{0, 5});
  REQUIRE(replayed.skips.size() == 4);
  CHECK(replayed.ended);
  for (std::size_t i = 0; i < 4; ++i) {
    INFO(replayed.skips[i]);
    CHECK(contains(replayed.skips[i].c_str(), frame_png(tum, static_cast<int>(i) + 1)));
    CHECK(replayed.skip_codes[i] == StatusCode::data_loss);
  }
  CHECK(contains(replayed.skips[0].c_str(), "corrupt or truncated PNG"));
  CHECK(contains(replayed.skips[1].c_str(), "corrupt or truncated PNG"));
  CHECK(contains(replayed.skips[2].c_str(), "not a PNG file"));
  CHECK(contains(replayed.skips[3].c_str(), "cannot open"));
}

TEST_CASE("a first frame that cannot be read fails open()", "[replay][bad]") {
  const std::string parent = fx::make_test_dir("bad-first");
  const fx::TumFixture tum = fx::write_tum(parent, "first", 2);
  fx::write_text(frame_png(tum, 0), "garbage");
  ReplaySource source(config_for("tum:" + tum.dir));
  CHECK(source.open() == StatusCode::data_loss);
  CHECK(contains(source.last_error(), frame_png(tum, 0) + ": not a PNG file"));
}

TEST_CASE("frames larger than the configured maximum", "[replay][bad]") {
  const std::string parent = fx::make_test_dir("bad-size");
  const fx::TumFixture tum = fx::write_tum(parent, "big", 2);
  ReplayConfig config = config_for("tum:" + tum.dir);
  config.max_width = 4;
  ReplaySource source(config);
  CHECK(source.open() == StatusCode::resource_exhausted);
  CHECK(contains(source.last_error(), "image is 8x6, larger than the configured maximum 4x480"));
}

TEST_CASE("more frames than max_frames", "[replay][bad]") {
  const std::string parent = fx::make_test_dir("bad-count");
  const fx::TumFixture tum = fx::write_tum(parent, "many", 5, false);
  const std::string seven = fx::write_seven_scenes(parent, 5);
  for (const std::string& spec : {"tum:" + tum.dir, "7scenes:" + seven}) {
    ReplayConfig config = config_for(spec);
    config.max_frames = 4;
    ReplaySource source(config);
    CHECK(source.open() == StatusCode::resource_exhausted);
    CHECK(contains(source.last_error(), "more than 4 frames"));
  }
}

TEST_CASE(".raw with a short last frame or absurd sizes", "[replay][bad]") {
  const std::string dir = fx::make_test_dir("bad-raw");
  const std::string two = fx::raw_frame_bytes(5, 4, 0) + fx::raw_frame_bytes(5, 4, 1);

  SECTION("short last frame: skipped, then end of stream") {
    const std::string third = fx::raw_frame_bytes(5, 4, 2);
    const std::string path = dir + "/short.raw";
    fx::write_text(path, two + third.substr(0, third.size() - 7));
    ReplaySource source(config_for("raw:" + path));
    REQUIRE(source.open().ok());
    CHECK(source.frame_count() == 3);
    const Replayed replayed = replay_all(source);
    CHECK(replayed.frames == std::vector<std::uint64_t>{0, 1});
    REQUIRE(replayed.skips.size() == 1);
    CHECK(contains(replayed.skips[0].c_str(), "short.raw: short frame at byte"));
    CHECK(replayed.ended);
  }
  SECTION("a few stray bytes at the end") {
    const std::string path = dir + "/tail.raw";
    fx::write_text(path, two + "abc");
    ReplaySource source(config_for("raw:" + path));
    REQUIRE(source.open().ok());
    const Replayed replayed = replay_all(source);
    CHECK(replayed.frames == std::vector<std::uint64_t>{0, 1});
    REQUIRE(replayed.skips.size() == 1);
    CHECK(contains(replayed.skips[0].c_str(), "only 3 bytes left"));
  }
  SECTION("absurd depth size in a later frame") {
    std::string third = fx::raw_frame_bytes(5, 4, 2);
    third[0] = '\xff';
    third[1] = '\xff';
    third[2] = '\xff';
    third[3] = '\x7f';
    const std::string path = dir + "/absurd.raw";
    fx::write_text(path, two + third);
    ReplaySource source(config_for("raw:" + path));
    REQUIRE(source.open().ok());
    const Replayed replayed = replay_all(source);
    CHECK(replayed.frames == std::vector<std::uint64_t>{0, 1});
    REQUIRE(replayed.skips.size() == 1);
    CHECK(contains(replayed.skips[0].c_str(), "absurd.raw: frame at byte"));
    CHECK(contains(replayed.skips[0].c_str(), "2147483647x4"));
    CHECK(replayed.ended);
  }
  SECTION("a corrupt header mid-file: that frame skipped, the ones after it still read") {
    std::string third = fx::raw_frame_bytes(5, 4, 2);
    third[0] = '\xff';
    third[1] = '\xff';
    third[2] = '\xff';
    third[3] = '\x7f';
    const std::string path = dir + "/middle.raw";
    fx::write_text(path, two + third + fx::raw_frame_bytes(5, 4, 3) + fx::raw_frame_bytes(5, 4, 4));
    ReplaySource source(config_for("raw:" + path));
    REQUIRE(source.open().ok());
    CHECK(source.frame_count() == 5);
    const Replayed replayed = replay_all(source);
    CHECK(replayed.frames == std::vector<std::uint64_t>{0, 1, 3, 4});
    REQUIRE(replayed.skips.size() == 1);
    CHECK(contains(replayed.skips[0].c_str(), "middle.raw: frame at byte"));
    CHECK(replayed.ended);
  }
  SECTION("garbage after two frames: each frame-sized slot counted as a skipped frame") {
    const std::size_t frame_size = fx::raw_frame_bytes(5, 4, 0).size();
    const std::string path = dir + "/garbage.raw";
    fx::write_text(path, two + std::string(2 * frame_size + 5, '\xee'));
    ReplaySource source(config_for("raw:" + path));
    REQUIRE(source.open().ok());
    CHECK(source.frame_count() == 5);
    const Replayed replayed = replay_all(source);
    CHECK(replayed.frames == std::vector<std::uint64_t>{0, 1});
    CHECK(replayed.skips.size() == 3);
    CHECK(replayed.ended);
    // A damaged tail longer than the index holds: it opens, its last slot standing for the rest.
    ReplayConfig small = config_for("raw:" + path);
    small.max_frames = 4;
    ReplaySource capped(small);
    REQUIRE(capped.open().ok());
    CHECK(capped.frame_count() == 4);
  }
  SECTION("absurd RGB size") {
    std::string first = fx::raw_frame_bytes(5, 4, 0);
    const std::size_t rgb_header = 8 + 5 * 4 * 2;
    first[rgb_header + 2] = '\x10';  // width 5 + 0x100000
    const std::string path = dir + "/rgb.raw";
    fx::write_text(path, first);
    ReplaySource source(config_for("raw:" + path));
    CHECK(source.open() == StatusCode::data_loss);
    CHECK(contains(source.last_error(), "absurd RGB size"));
  }
  SECTION("zero-sized first frame") {
    const std::string path = dir + "/zero.raw";
    fx::write_text(path, std::string(16, '\0'));
    ReplaySource source(config_for("raw:" + path));
    CHECK(source.open() == StatusCode::data_loss);
    CHECK(contains(source.last_error(), "zero.raw: frame at byte 0 has an empty depth image"));
  }
  SECTION("empty file") {
    const std::string path = dir + "/empty.raw";
    fx::write_text(path, "");
    ReplaySource source(config_for("raw:" + path));
    CHECK(source.open() == StatusCode::data_loss);
    CHECK(contains(source.last_error(), "empty.raw: empty file"));
  }
}

TEST_CASE("a 7-Scenes frame missing between others is skipped, not the end", "[replay][bad]") {
  const std::string parent = fx::make_test_dir("bad-seven-gap");
  const std::string dir = fx::write_seven_scenes(parent, 6);
  std::remove((dir + "/frame-000002.depth.png").c_str());
  std::remove((dir + "/frame-000003.depth.png").c_str());
  fx::write_text(dir + "/frame-00004.depth.png", "a name with five digits is not a frame");
  ReplaySource source(config_for("7scenes:" + dir));
  REQUIRE(source.open().ok());
  CHECK(source.frame_count() == 6);
  const Replayed replayed = replay_all(source);
  CHECK(replayed.frames == std::vector<std::uint64_t>{0, 1, 4, 5});
  REQUIRE(replayed.skips.size() == 2);
  CHECK(contains(replayed.skips[0].c_str(), dir + "/frame-000002.depth.png: cannot open"));
  CHECK(contains(replayed.skips[1].c_str(), dir + "/frame-000003.depth.png: cannot open"));
  CHECK(replayed.ended);
}

TEST_CASE("timestamps too large for microseconds are refused", "[replay][bad]") {
  // 1e300 s overflowed the conversion to microseconds (undefined behaviour).
  const std::string parent = fx::make_test_dir("bad-huge-time");
  SECTION("in depth.txt") {
    const fx::TumFixture tum = fx::write_tum(parent, "huge");
    fx::write_text(tum.dir + "/depth.txt", "1.0 depth/a.png\n1e300 depth/b.png\n");
    ReplaySource source(config_for("tum:" + tum.dir));
    CHECK(source.open() == StatusCode::data_loss);
    CHECK(contains(source.last_error(), "depth.txt:2: timestamp 1e+300 s is outside [0, 1e+11] s"));
  }
  SECTION("negative, in depth.txt") {
    const fx::TumFixture tum = fx::write_tum(parent, "negative");
    fx::write_text(tum.dir + "/depth.txt", "-5.0 depth/a.png\n");
    ReplaySource source(config_for("tum:" + tum.dir));
    CHECK(source.open() == StatusCode::data_loss);
    CHECK(contains(source.last_error(), "depth.txt:1: timestamp -5 s is outside"));
  }
  SECTION("in groundtruth.txt") {
    const fx::TumFixture tum = fx::write_tum(parent, "gthuge");
    fx::write_text(tum.dir + "/groundtruth.txt", "1e300 0 0 0 0 0 0 1\n");
    ReplaySource source(config_for("tum:" + tum.dir));
    CHECK(source.open() == StatusCode::data_loss);
    CHECK(contains(source.last_error(), "groundtruth.txt:1: timestamp 1e+300 s is outside"));
  }
}
