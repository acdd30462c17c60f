#include "octofuse/ports/replay/text_parsers.hpp"

#include <catch2/catch.hpp>
#include <cstring>
#include <string>

using octofuse::ErrorText;
using octofuse::StatusCode;
namespace rp = octofuse::replay;

namespace {
constexpr double kTolerance = 1e-12;
}

TEST_CASE("LineReader handles LF, CRLF, CR and a missing final newline", "[replay][text]") {
  const std::string text = "a\nbb\r\n\rccc";
  rp::LineReader lines(text.data(), text.size());
  const char* line;
  std::size_t length;
  std::vector<std::string> got;
  while (lines.next(&line, &length)) got.emplace_back(line, length);
  CHECK(got == std::vector<std::string>{"a", "bb", "", "ccc"});
  CHECK(lines.line_number() == 4);
  CHECK(rp::is_blank_or_comment("  # x", 5));
  CHECK(rp::is_blank_or_comment(" \t", 2));
  CHECK_FALSE(rp::is_blank_or_comment(" 1 #", 4));
}

TEST_CASE("parse_double reads decimal numbers only", "[replay][text]") {
  const char* ok_inputs[] = {"1.5", " -2e-3", "+7", "1305031102.175304"};
  const double ok_values[] = {1.5, -2e-3, 7.0, 1305031102.175304};
  for (int i = 0; i < 4; ++i) {
    const char* p = ok_inputs[i];
    double v = 0.0;
    REQUIRE(rp::parse_double(&p, ok_inputs[i] + std::strlen(ok_inputs[i]), &v));
    CHECK(v == Approx(ok_values[i]).epsilon(kTolerance));
  }
  for (const char* bad : {"", "abc", "1.5x", "nan", "inf", "+", "-"}) {
    const char* p = bad;
    double v = 0.0;
    INFO(bad);
    CHECK_FALSE(rp::parse_double(&p, bad + std::strlen(bad), &v));
    CHECK(p == bad);
  }
}

TEST_CASE("timestamped names and TUM pose lines", "[replay][text]") {
  ErrorText error;
  rp::TimestampedName name;
  const std::string line = "1305031102.160407 depth/1305031102.160407.png extra";
  REQUIRE(rp::parse_timestamped_name(line.data(), line.size(), &name, "depth.txt", 4, &error).ok());
  CHECK(name.timestamp_s == Approx(1305031102.160407).epsilon(kTolerance));
  CHECK(std::string(name.name, name.name_length) == "depth/1305031102.160407.png");

  rp::TimestampedPose pose;
  const std::string gt = "1.25 1 2 3 0 0 0.6 0.8";
  REQUIRE(rp::parse_tum_pose_line(gt.data(), gt.size(), &pose, "gt.txt", 1, &error).ok());
  CHECK(pose.timestamp_s == 1.25);
  CHECK(pose.t_W_C == Eigen::Vector3d(1, 2, 3));
  CHECK(pose.q_W_C.z() == Approx(0.6));
  CHECK(pose.q_W_C.w() == Approx(0.8));

  const std::string extra = "1.25 1 2 3 0 0 0.6 0.8 9";
  CHECK(rp::parse_tum_pose_line(extra.data(), extra.size(), &pose, "gt.txt", 7, &error) ==
        StatusCode::data_loss);
  CHECK(std::string(error.c_str()) ==
        "gt.txt:7: expected 8 numbers (timestamp tx ty tz qx qy qz qw) and nothing after them");
}

TEST_CASE("pose matrices must be rigid", "[replay][text]") {
  ErrorText error;
  Eigen::Matrix4d T;
  const std::string rigid = "0 -1 0 1\n1 0 0 2\n0 0 1 3\n0 0 0 1\n";
  REQUIRE(rp::parse_pose_matrix(rigid.data(), rigid.size(), &T, "p.txt", &error).ok());
  CHECK(T(0, 1) == -1.0);
  CHECK(T(2, 3) == 3.0);
  const std::string reflection = "-1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n";
  CHECK(rp::parse_pose_matrix(reflection.data(), reflection.size(), &T, "p.txt", &error) ==
        StatusCode::data_loss);
  CHECK(std::string(error.c_str()).find("p.txt: not a rigid transform (rotation determinant -1") ==
        0);
  const std::string bottom = "1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 1 1\n";
  CHECK(rp::parse_pose_matrix(bottom.data(), bottom.size(), &T, "p.txt", &error) ==
        StatusCode::data_loss);
}

TEST_CASE("intrinsics from a matrix file and from a list", "[replay][text]") {
  ErrorText error;
  octofuse::PinholeCamera camera;
  const std::string k = "585 0 320\n0 586 240\n0 0 1\n";
  REQUIRE(rp::parse_intrinsics_matrix(k.data(), k.size(), &camera, "k.txt", &error).ok());
  CHECK(camera.fx == 585.0f);
  CHECK(camera.fy == 586.0f);
  CHECK(camera.cx == 320.0f);
  CHECK(camera.cy == 240.0f);
  const std::string skew = "585 1 320\n0 586 240\n0 0 1\n";
  CHECK(rp::parse_intrinsics_matrix(skew.data(), skew.size(), &camera, "k.txt", &error) ==
        StatusCode::data_loss);

  REQUIRE(rp::parse_intrinsics_list("525,526.5,319.5,239.5", &camera, &error).ok());
  CHECK(camera.fy == 526.5f);
  CHECK(rp::parse_intrinsics_list("525,526", &camera, &error) == StatusCode::invalid_argument);
  CHECK(rp::parse_intrinsics_list("-1,1,1,1", &camera, &error) == StatusCode::invalid_argument);
  CHECK(std::string(error.c_str()) ==
        "intrinsics \"-1,1,1,1\": expected fx,fy,cx,cy with fx, fy > 0");
}
