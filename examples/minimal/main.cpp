// The smallest program that maps: depth frames from the sim camera, a pipeline over one buffer,
// a query of the map, and a mesh. Built against the installed package (see CMakeLists.txt).
// Exit status 0 when it mapped the desk and found the surface it should.
#include <cstdio>
#include <cstdlib>
#include <memory>

#include <octofuse/mesh/mesher.hpp>
#include <octofuse/pipeline/pipeline.hpp>
#include <octofuse/ports/sim/sim_source.hpp>
#include <octofuse/query/map_query.hpp>

using namespace octofuse;

namespace {

// The one place this program asks the map about a point: the signed distance in metres near a
// surface, or false where the map says something else (free, unknown, inside, outside the cube).
bool signed_distance_m(const Pipeline<MultiresVoxel>& pipeline, const Eigen::Vector3f& p_W,
                       float* distance_m) {
  const Result<PointAnswer> answer = pipeline.query().point(p_W);
  if (!answer.ok() || answer.value().state != PointState::near) return false;
  *distance_m = answer.value().distance_m;
  return true;
}

// Counts what the mesher streams out; a real program would write it or hand it on.
class CountingSink final : public MeshSink {
 public:
  Status add_vertices(const MeshVertex*, std::size_t count) override {
    vertices += count;
    return ok_status();
  }
  Status add_triangles(const MeshTriangle*, std::size_t count) override {
    triangles += count;
    return ok_status();
  }
  std::size_t vertices = 0, triangles = 0;
};

int fail(const char* what, const char* why) {
  std::fprintf(stderr, "error: %s: %s\n", what, why);
  return 1;
}

}  // namespace

int main() {
  // 1. A depth source: the built-in desk scene, 60 frames, with ground truth.
  ErrorText error;
  std::unique_ptr<sim::SimSource> source = sim::make_sim_source("sim:desk,frames=60", &error);
  if (source == nullptr) return fail("source", error.c_str());
  if (!source->open().ok()) return fail("source", source->last_error());

  // 2. The pipeline: 2 cm voxels in a 5.12 m cube in front of the first camera, all memory in one
  // buffer sized by bytes_required().
  const Se3d T_W_C0 = source->ground_truth_T_W_C(0);
  const Eigen::Vector3f centre_W = (T_W_C0 * Eigen::Vector3d(0.0, 0.0, 1.5)).cast<float>();
  PipelineConfig config = default_pipeline_config(source->intrinsics(), 0.02f, 8, 40000, centre_W);
  config.initial_T_W_C = T_W_C0;
  const std::size_t bytes = bytes_required(config);
  if (bytes == 0) return fail("configuration", "bytes_required() is 0");
  void* buffer = std::aligned_alloc(kArenaAlignment, align_up(bytes, kArenaAlignment));
  Pipeline<MultiresVoxel> pipeline;
  if (!pipeline.init(buffer, bytes, config).ok()) return fail("init", pipeline.last_error());

  // 3. Feed frames. process() allocates nothing; a lost frame is a state, not an error.
  DepthFrame frame;
  FrameStats stats;
  int tracked = 0;
  while (source->next(frame).outcome == FrameOutcome::frame) {
    const Status status = pipeline.process(frame, &stats);
    if (!status.ok() && stats.result != FrameResult::lost) {
      return fail("process", pipeline.last_error());
    }
    if (stats.result == FrameResult::tracked || stats.result == FrameResult::first) ++tracked;
  }

  // 4. Query: walk from the last camera along its view until the signed distance changes sign,
  // and ask whether a 10 cm sphere halfway to that surface is free (the robot's body there).
  const Se3d T_W_C = pipeline.T_W_C();
  const Eigen::Vector3f origin_W = T_W_C.translation().cast<float>();
  const Eigen::Vector3f ray_W = T_W_C.linear().col(2).cast<float>();
  float hit_m = -1.0f;
  float previous = 0.0f;
  bool have_previous = false;
  for (float t = 0.4f; t < 4.0f && hit_m < 0.0f; t += 0.01f) {
    float d = 0.0f;
    const bool known = signed_distance_m(pipeline, origin_W + t * ray_W, &d);
    if (known && have_previous && previous > 0.0f && d <= 0.0f) hit_m = t;
    have_previous = known;
    previous = d;
  }

  const float body_m = hit_m > 0.0f ? 0.5f * hit_m : 1.0f;
  const Result<RegionAnswer> body = pipeline.query().sphere(origin_W + body_m * ray_W, 0.1f);
  if (!body.ok()) return fail("query", body.status().name());

  // 5. Mesh the map.
  MeshConfig mesh_config;
  mesh_config.vertex_capacity = 1u << 18;
  const std::size_t mesh_bytes = Mesher<MultiresVoxel>::bytes_required(mesh_config);
  void* mesh_buffer = std::aligned_alloc(kArenaAlignment, align_up(mesh_bytes, kArenaAlignment));
  LinearArena arena(mesh_buffer, mesh_bytes);
  Mesher<MultiresVoxel> mesher;
  CountingSink mesh;
  if (!mesher.reserve(arena, mesh_config).ok() || !mesher.extract(pipeline.map(), mesh).ok()) {
    return fail("mesh", "extraction failed");
  }

  std::printf(
      "%d of 60 frames tracked, %u blocks; surface %.2f m ahead of the camera; a 10 cm sphere "
      "%.2f m ahead is %s; mesh %zu vertices, %zu triangles\n",
      tracked, pipeline.map().memory().blocks_used, static_cast<double>(hit_m),
      static_cast<double>(body_m), region_state_name(body.value().state), mesh.vertices,
      mesh.triangles);
  std::free(mesh_buffer);
  std::free(buffer);
  return tracked == 60 && hit_m > 0.0f && mesh.triangles > 0 ? 0 : 2;
}
