// --query-points with a distance field: a free point's DISTANCE becomes the field's lower bound
// where that is larger than the free octant's, and stays a lower bound (a wall 2 m ahead).

#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <catch2/catch.hpp>

#include "octofuse/query/esdf.hpp"
#include "query_points.hpp"
#include "support/test_dir.hpp"
#include "unit/query/query_support.hpp"

namespace octofuse {
namespace {

TEST_CASE("--query-points answers free points with the distance field's lower bound") {
  Mapper m;
  for (int i = 0; i < 3; ++i) m.fuse(wall_at(kWall_m));
  EsdfConfig config;
  config.enabled = true;
  config.cells_per_side = 128;  // the whole cube: no open faces
  config.cell_voxels = 2;
  config.max_cell_steps = 0;
  test::ArenaBuffer memory(EsdfField::bytes_required(config));
  EsdfField field;
  REQUIRE(field.reserve(memory.arena(), config, m.map_config).ok());
  REQUIRE(field.flush(m.map, &m.free_space, kMu_m, m.frame, 1).published);

  const std::vector<Eigen::Vector3f> points = {Eigen::Vector3f(0.0f, 0.0f, 1.0f),
                                               Eigen::Vector3f(0.1f, -0.1f, 1.5f)};
  const std::string dir = test::make_test_dir("query_points_esdf");
  REQUIRE(!dir.empty());
  const std::string plain = dir + "/plain.txt";
  const std::string with_field = dir + "/field.txt";
  std::string error;
  REQUIRE(examples::write_query_answers(m.query(), points, plain, &error));
  REQUIRE(examples::write_query_answers(m.query(), points, with_field, &error, &field));
  std::ifstream a(plain);
  std::ifstream b(with_field);
  for (const Eigen::Vector3f& p : points) {
    float x, y, z, d_plain, d_field;
    std::string state_plain, state_field;
    REQUIRE(a >> x >> y >> z >> state_plain >> d_plain);
    REQUIRE(b >> x >> y >> z >> state_field >> d_field);
    REQUIRE(state_plain == "free");
    REQUIRE(state_field == "free");
    const float exact = static_cast<float>(kWall_m) - p.z();
    CHECK(d_field >= d_plain);
    CHECK(d_field <= exact);
    CHECK(d_field >= exact - field.error_bound_m() - kVoxel_m);
  }
}

}  // namespace
}  // namespace octofuse
