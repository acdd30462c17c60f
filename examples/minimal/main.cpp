// The smallest program that maps: depth frames from the sim camera into a Mapper, a question to
// the map, and a mesh. Built against the installed package (see CMakeLists.txt).
// Exit status 0 when it mapped the desk and found the surface it should.
#include <cstdio>
#include <memory>

#include <octofuse/pipeline/mapper.hpp>
#include <octofuse/ports/sim/sim_source.hpp>

using namespace octofuse;

static int fail(const char* why) {
  std::fprintf(stderr, "error: %s\n", why);
  return 1;
}

int main() {
  // 1. A depth source: the built-in desk scene, 60 frames, with ground truth.
  ErrorText error;
  std::unique_ptr<sim::SimSource> source = sim::make_sim_source("sim:desk,frames=60", &error);
  if (source == nullptr) return fail(error.c_str());
  if (!source->open().ok()) return fail(source->last_error());

  // 2. The mapper: 2 cm voxels in a 5.12 m cube ahead of the first camera; all memory now.
  MapperSettings settings;
  settings.first_T_W_C = source->ground_truth_T_W_C(0);
  Mapper<> mapper;
  if (!mapper.init(source->intrinsics(), settings).ok()) return fail(mapper.last_error());

  // 3. Feed frames. process() allocates nothing; a lost frame is a state, not an error.
  DepthFrame frame;
  FrameStats stats;
  int tracked = 0;
  while (source->next(frame).outcome == FrameOutcome::frame) {
    const Status status = mapper.process(frame, &stats);
    if (!status.ok() && stats.result != FrameResult::lost) return fail(mapper.last_error());
    if (stats.result == FrameResult::tracked || stats.result == FrameResult::first) ++tracked;
  }

  // 4. Ask the map: walk from the camera along its view until the signed distance of a point
  // near a surface turns negative, then whether a 10 cm sphere halfway there is free.
  const Eigen::Vector3f origin_W = mapper.T_W_C().translation().cast<float>();
  const Eigen::Vector3f ray_W = mapper.T_W_C().linear().col(2).cast<float>();
  float hit_m = -1.0f;
  float previous_m = -1.0f;  // the last near point's signed distance (-1: none just before)
  for (float t = 0.4f; t < 4.0f && hit_m < 0.0f; t += 0.01f) {
    const Result<PointAnswer> answer = mapper.query().point(origin_W + t * ray_W);
    const bool near = answer.ok() && answer.value().state == PointState::near;
    if (near && previous_m > 0.0f && answer.value().distance_m <= 0.0f) hit_m = t;
    previous_m = near ? answer.value().distance_m : -1.0f;
  }
  const float body_m = hit_m > 0.0f ? 0.5f * hit_m : 1.0f;
  const Result<RegionAnswer> body = mapper.query().sphere(origin_W + body_m * ray_W, 0.1f);

  // 5. The mesh: vertices and triangles in memory the mapper reserved.
  const Result<const MeshBuffer*> mesh = mapper.extract_mesh();
  if (!body.ok()) return fail(body.status().name());
  if (!mesh.ok()) return fail(mapper.last_error());
  std::printf(
      "%d of 60 frames tracked, %u blocks; surface %.2f m ahead of the camera; a 10 cm "
      "sphere %.2f m ahead is %s; mesh %zu vertices, %zu triangles\n",
      tracked, mapper.map().memory().blocks_used, static_cast<double>(hit_m),
      static_cast<double>(body_m), region_state_name(body.value().state),
      mesh.value()->vertices().size(), mesh.value()->triangles().size());
  return tracked == 60 && hit_m > 0.0f && mesh.value()->triangles().size() > 0 ? 0 : 2;
}
