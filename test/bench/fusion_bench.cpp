// Multires vs single-res integration in the same run: a desk-like analytic scene, QVGA, ground
// truth poses, one worker, at 1 cm and 2 mm finest voxels (mu = 8 voxels). Prints per-frame
// integration CPU times (median and mean), the ratio and the memory each map uses.
//
//   bench_fusion [frames] [workers] [1cm|2mm|all] [small]
//   (Release build; defaults: 40 frames, 1 worker, both settings, huge pages)

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <memory>
#include <vector>

#include <sys/mman.h>

#include "octofuse/fusion/integrator.hpp"
#include "support/analytic_scene.hpp"
#include "support/camera.hpp"

namespace octofuse {
namespace {

// CPU time of this process: on a shared, loaded machine wall time measures the neighbours. With
// one worker it is the integration's own time; with more it is the sum over workers.
double cpu_ms() {
  return 1e3 * static_cast<double>(std::clock()) / CLOCKS_PER_SEC;
}

struct FreeDeleter {
  void operator()(unsigned char* p) const { std::free(p); }
};

// World: y down, the camera looks across a desk top (plane y = 0.7) towards a wall.
test::AnalyticScene desk_scene() {
  test::AnalyticScene s;
  s.planes.push_back({Eigen::Vector3d(0, 1, 0), 0.7});                        // desk top
  s.planes.push_back({Eigen::Vector3d(0, 0, 1), 2.4});                        // back wall
  s.planes.push_back({Eigen::Vector3d(1, 0, 0), -1.2});                       // side wall
  s.spheres.push_back({Eigen::Vector3d(0.25, 0.55, 1.3), 0.15});              // a ball
  s.spheres.push_back({Eigen::Vector3d(0.0, 0.65, 0.95), 0.05});              // a small ball
  s.cylinders.push_back({Eigen::Vector3d(-0.15, 0, 1.1), 0.045, 0.58, 0.7});  // mug
  s.cylinders.push_back({Eigen::Vector3d(-0.09, 0, 1.1), 0.006, 0.6, 0.68});  // handle
  s.cylinders.push_back({Eigen::Vector3d(0.45, 0, 1.6), 0.01, 0.3, 0.7});     // lamp pole
  return s;
}

Se3d look_at(const Eigen::Vector3d& position, const Eigen::Vector3d& target) {
  const Eigen::Vector3d z = (target - position).normalized();
  const Eigen::Vector3d x = Eigen::Vector3d(0, 1, 0).cross(z).normalized();
  const Eigen::Vector3d y = z.cross(x);
  Se3d T = Se3d::Identity();
  T.linear().col(0) = x;
  T.linear().col(1) = y;
  T.linear().col(2) = z;
  T.translation() = position;
  return T;
}

Se3d trajectory(int frame, int frames) {
  const double a = frames > 1 ? static_cast<double>(frame) / (frames - 1) : 0.0;
  const Eigen::Vector3d position(-0.4 + 0.8 * a, 0.1, 0.2 + 0.3 * a);
  return look_at(position, Eigen::Vector3d(0.0, 0.6, 1.3));
}

template <typename VoxelT>
struct Fusion {
  Fusion(const MapConfig& mc, const FusionConfig& fc, const PinholeCamera& camera,
         bool huge_pages) {
    bytes = Octree<VoxelT>::bytes_required(mc) +
            Integrator<VoxelT>::bytes_required(fc, camera.width, camera.height);
    // 2 MiB alignment and huge pages, as a deployment would use for a map of hundreds of MB:
    // block lookups jump across the whole pool and 4 KiB pages make every jump a TLB miss.
    constexpr std::size_t kHugePage = std::size_t{2} << 20;
    bytes = align_up(bytes, kHugePage);
    memory.reset(static_cast<unsigned char*>(std::aligned_alloc(kHugePage, bytes)));
    if (huge_pages) madvise(memory.get(), bytes, MADV_HUGEPAGE);
    LinearArena arena(memory.get(), bytes);
    if (!map.reserve(arena, mc).ok() ||
        !integrator.reserve(arena, fc, camera.width, camera.height).ok()) {
      std::fprintf(stderr, "reserve failed\n");
      std::exit(1);
    }
  }
  std::size_t bytes = 0;
  std::unique_ptr<unsigned char, FreeDeleter> memory;
  Octree<VoxelT> map;
  Integrator<VoxelT> integrator;
  std::vector<double> ms;
  std::uint64_t refusals = 0;
};

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}
double mean(const std::vector<double>& v) {
  double s = 0.0;
  for (double x : v) s += x;
  return v.empty() ? 0.0 : s / static_cast<double>(v.size());
}

void run(float voxel_size_m, int voxel_depth, std::uint32_t blocks, int frames, int workers,
         bool huge_pages) {
  const PinholeCamera camera = test::centred_camera(320, 240, 262.5f);
  const MapConfig mc = MapConfig::centred(Eigen::Vector3f(0.0f, 0.4f, 1.2f), voxel_size_m,
                                          voxel_depth, blocks, blocks);
  FusionConfig fc;
  fc.mu_m = 8.0f * voxel_size_m;
  fc.max_blocks_per_frame = 1u << 16;
  Fusion<TsdfVoxel> single(mc, fc, camera, huge_pages);
  Fusion<MultiresVoxel> multires(mc, fc, camera, huge_pages);
  const test::AnalyticScene scene = desk_scene();
  WorkerTeam team(workers);
  std::vector<float> depth;
  std::uint32_t per_scale[4] = {0, 0, 0, 0};
  for (int f = 0; f < frames; ++f) {
    const Se3d T_W_C = trajectory(f, frames);
    scene.render(camera, T_W_C, depth);
    const ImageView<const float> view(depth.data(), camera.width, camera.height);
    const double t0 = cpu_ms();
    const IntegrationReport rs = single.integrator.integrate(
        single.map, view, camera, T_W_C, static_cast<std::uint32_t>(f), FusionBudget(), team);
    const double t1 = cpu_ms();
    const IntegrationReport rm = multires.integrator.integrate(
        multires.map, view, camera, T_W_C, static_cast<std::uint32_t>(f), FusionBudget(), team);
    const double t2 = cpu_ms();
    single.ms.push_back(t1 - t0);
    multires.ms.push_back(t2 - t1);
    single.refusals += rs.pool_refusals;
    multires.refusals += rm.pool_refusals;
    for (int s = 0; s < 4; ++s) per_scale[s] += rm.blocks_per_scale[s];
  }
  const MapMemory ms = single.map.memory();
  const MapMemory mm = multires.map.memory();
  std::printf("voxel %.1f mm, mu %.1f cm, %d frames QVGA, %d worker(s), %s pages\n",
              voxel_size_m * 1e3, fc.mu_m * 1e2, frames, workers, huge_pages ? "huge" : "4 KiB");
  std::printf(
      "  single-res: median %8.2f ms  mean %8.2f ms  blocks %7u  map %8.1f MB  refused %llu\n",
      median(single.ms), mean(single.ms), ms.blocks_used, ms.bytes_used / 1e6,
      static_cast<unsigned long long>(single.refusals));
  std::printf(
      "  multires:   median %8.2f ms  mean %8.2f ms  blocks %7u  map %8.1f MB  refused %llu\n",
      median(multires.ms), mean(multires.ms), mm.blocks_used, mm.bytes_used / 1e6,
      static_cast<unsigned long long>(multires.refusals));
  std::printf("  multires blocks integrated by scale: %u / %u / %u / %u; finest levels held %u\n",
              per_scale[0], per_scale[1], per_scale[2], per_scale[3], mm.finest_used);
  std::printf("  speed-up (single / multires): median %.2fx, mean %.2fx\n",
              median(single.ms) / median(multires.ms), mean(single.ms) / mean(multires.ms));
}

}  // namespace
}  // namespace octofuse

int main(int argc, char** argv) {
  const int frames = argc > 1 ? std::atoi(argv[1]) : 40;
  const int workers = argc > 2 ? std::atoi(argv[2]) : 1;
  // Third argument: "1cm" or "2mm" runs only that setting.
  const char* only = argc > 3 ? argv[3] : "";
  // Fourth argument "small" keeps 4 KiB pages.
  const bool huge = !(argc > 4 && argv[4][0] == 's');
  if (only[0] == '\0' || only[0] == 'a' || only[0] == '1')
    octofuse::run(0.01f, 10, 60000, frames, workers, huge);
  if (only[0] == '\0' || only[0] == 'a' || only[0] == '2')
    octofuse::run(0.002f, 12, 250000, frames, workers, huge);
  return 0;
}
