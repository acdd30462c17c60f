#include "octofuse/ports/host/ply.hpp"

#include <catch2/catch.hpp>
#include <cstdio>
#include <fstream>

#include "support/test_dir.hpp"

using octofuse::ErrorText;
using octofuse::StatusCode;
using octofuse::host::Mesh;
using octofuse::test::read_bytes;

namespace {

Mesh tetrahedron(bool with_scale) {
  Mesh mesh;
  mesh.vertices = {
      {0.0f, 0.0f, 0.0f}, {1.5f, 0.0f, 0.0f}, {0.0f, -2.25f, 0.0f}, {0.0f, 0.0f, 1e-3f}};
  mesh.indices = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3};
  if (with_scale) mesh.vertex_scale = {0, 1, 2, 3};
  return mesh;
}

std::size_t file_size(const std::string& path) {
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  return static_cast<std::size_t>(in.tellg());
}

}  // namespace

TEST_CASE("PLY round trip is exact, with and without the scale property", "[host][ply]") {
  const std::string dir = octofuse::test::make_test_dir("ply");
  for (bool with_scale : {false, true}) {
    const Mesh written = tetrahedron(with_scale);
    const std::string path = dir + (with_scale ? "/scaled.ply" : "/plain.ply");
    ErrorText error;
    REQUIRE(octofuse::host::write_ply(path.c_str(), written.view(), &error).ok());
    Mesh read;
    REQUIRE(octofuse::host::read_ply(path.c_str(), &read, &error).ok());
    CHECK(read.vertices == written.vertices);
    CHECK(read.indices == written.indices);
    CHECK(read.vertex_scale == written.vertex_scale);
  }
}

TEST_CASE("PLY writer refuses out-of-range indices", "[host][ply]") {
  const std::string dir = octofuse::test::make_test_dir("ply-bad-index");
  Mesh mesh = tetrahedron(false);
  mesh.indices[4] = 4;
  ErrorText error;
  const std::string path = dir + "/bad.ply";
  CHECK(octofuse::host::write_ply(path.c_str(), mesh.view(), &error) ==
        StatusCode::invalid_argument);
  CHECK(std::string(error.c_str()).find("vertex 4") != std::string::npos);
}

TEST_CASE("PLY reader reports truncated and malformed files", "[host][ply]") {
  const std::string dir = octofuse::test::make_test_dir("ply-bad");
  const std::string good = dir + "/good.ply";
  ErrorText error;
  REQUIRE(octofuse::host::write_ply(good.c_str(), tetrahedron(true).view(), &error).ok());
  Mesh read;

  SECTION("missing") {
    const std::string path = dir + "/none.ply";
    CHECK(octofuse::host::read_ply(path.c_str(), &read, &error) == StatusCode::unavailable);
  }
  SECTION("truncated body") {
    const std::string bytes = read_bytes(good);
    const std::string path = dir + "/short.ply";
    std::ofstream(path, std::ios::binary) << bytes.substr(0, bytes.size() - 5);
    REQUIRE(file_size(path) + 5 == file_size(good));
    CHECK(octofuse::host::read_ply(path.c_str(), &read, &error) == StatusCode::data_loss);
    CHECK(std::string(error.c_str()).find("short.ply: truncated") != std::string::npos);
    CHECK(read.vertices.empty());
  }
  SECTION("a header promising more than the body holds, or bytes after it") {
    const std::string bytes = read_bytes(good);
    const std::string huge = dir + "/huge.ply";
    std::string promised = bytes;
    const std::size_t at = promised.find("element vertex 4");
    REQUIRE(at != std::string::npos);
    promised.replace(at, 16, "element vertex 2000000000");
    std::ofstream(huge, std::ios::binary) << promised;
    CHECK(octofuse::host::read_ply(huge.c_str(), &read, &error) == StatusCode::data_loss);
    CHECK(std::string(error.c_str()).find("huge.ply: truncated: the header promises 2000000000") !=
          std::string::npos);
    const std::string longer = dir + "/longer.ply";
    std::ofstream(longer, std::ios::binary) << bytes << "xyz";
    CHECK(octofuse::host::read_ply(longer.c_str(), &read, &error) == StatusCode::data_loss);
    CHECK(std::string(error.c_str()).find("longer.ply: 3 bytes after the last face") !=
          std::string::npos);
    CHECK(read.vertices.empty());
  }
  SECTION("ascii format") {
    const std::string path = dir + "/ascii.ply";
    std::ofstream(path) << "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\n"
                           "property float y\nproperty float z\nend_header\n";
    CHECK(octofuse::host::read_ply(path.c_str(), &read, &error) == StatusCode::data_loss);
  }
  SECTION("not a PLY") {
    const std::string path = dir + "/text.ply";
    std::ofstream(path) << "hello\n";
    CHECK(octofuse::host::read_ply(path.c_str(), &read, &error) == StatusCode::data_loss);
    CHECK(std::string(error.c_str()).find("not a PLY") != std::string::npos);
  }
}

TEST_CASE("PLY writer replaces a mesh whole or leaves the old one", "[host][ply]") {
  const std::string dir = octofuse::test::make_test_dir("ply-atomic");
  const std::string path = dir + "/mesh.ply";
  ErrorText error;
  const Mesh first = tetrahedron(false);
  REQUIRE(octofuse::host::write_ply(path.c_str(), first.view(), &error).ok());
  // A failed write (bad index) leaves the previous file as it was and no temporary beside it.
  Mesh bad = tetrahedron(true);
  bad.indices[0] = 9;
  CHECK(octofuse::host::write_ply(path.c_str(), bad.view(), &error) ==
        StatusCode::invalid_argument);
  Mesh read;
  REQUIRE(octofuse::host::read_ply(path.c_str(), &read, &error).ok());
  CHECK(read.vertices == first.vertices);
  CHECK(read.vertex_scale.empty());
  CHECK(!std::ifstream(path + ".tmp").good());
  // A good one replaces it.
  const Mesh second = tetrahedron(true);
  REQUIRE(octofuse::host::write_ply(path.c_str(), second.view(), &error).ok());
  REQUIRE(octofuse::host::read_ply(path.c_str(), &read, &error).ok());
  CHECK(read.vertex_scale == second.vertex_scale);
  CHECK(!std::ifstream(path + ".tmp").good());
  // A folder that does not exist: unavailable, nothing created.
  const std::string missing = dir + "/no-such-folder/mesh.ply";
  CHECK(octofuse::host::write_ply(missing.c_str(), second.view(), &error) ==
        StatusCode::unavailable);
}
