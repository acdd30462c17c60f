// octofuse-query-bench: how far a planner can trust the map's answers, and what they cost.
// For each sim scene: the default run (ICP tracking) with free space on, then
//   - safety: over random points in the map's cube, compared with the scene's exact signed
//     distance, the points reported free within one finest voxel of a surface or inside an object
//     (must be zero); the same for random boxes, spheres and swept spheres reported free;
//   - coverage: of the points truly free (> one voxel from any surface) that some camera saw
//     (in its image, within the depth range, nothing in between), the share reported free;
//   - accuracy: RMSE of the signed distance of points reported near against the exact one;
//   - cost: point, 0.5 m box and 0.3 m sphere swept over 1 m, median / p99 time per call and the
//     most visits one region query needed;
// and the same run with free space off, for the frame time and memory free space adds.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

#include "cli.hpp"
#include "octofuse/ports/sim/sim_source.hpp"
#include "runner.hpp"
#include "sim_visibility.hpp"

namespace {

using octofuse::MapQuery;
using octofuse::MultiresVoxel;
using octofuse::PointState;
using octofuse::RegionState;
using octofuse::examples::percentiles;
using octofuse::examples::RunOptions;
using octofuse::examples::RunSummary;

struct Figures {
  long points = 0;
  long reported_free = 0;
  long unsafe_points = 0;  // reported free, within one voxel of a surface or inside
  // Reported free with a distance above the exact one + 1 cm (the bound must hold).
  long over_bound_points = 0;
  double worst_over_bound = 0.0;   // the most a free point's distance exceeded the exact one
  double free_distance_sum = 0.0;  // reported distances of the free points (how tight the bound is)
  double free_exact_sum = 0.0;     // their exact distances
  long truly_free_in_view = 0;
  long truly_free_in_view_reported_free = 0;
  long truly_free_in_view_free_or_near = 0;  // free, or near with a positive distance
  long near_points = 0;
  double near_sq_error = 0.0;
  std::vector<double> near_abs_error;  // |reported - exact| of the near points within mu
  long close_points = 0;               // reported near, within 3 finest voxels of the surface
  double close_sq_error = 0.0;
  long missed[5] = {0, 0, 0, 0, 0};  // truly free in view, by reported state
  // Truly free in view and reported unknown, by exact distance to the nearest surface (m):
  // < 0.1, < 0.2, < 0.4, < 0.8, beyond.
  long unknown_by_distance[5] = {0, 0, 0, 0, 0};
  long regions = 0;
  long regions_free = 0;
  long unsafe_regions = 0;
  double point_us[2] = {0, 0};  // median, p99
  double box_us[2] = {0, 0};
  double swept_us[2] = {0, 0};
  std::uint32_t box_max_visits = 0;
  std::uint32_t swept_max_visits = 0;
  double ms_total_on = 0, ms_total_off = 0, ms_free_space = 0;
  double map_mb_on = 0, map_mb_off = 0, free_mb = 0;
};

// The least exact distance over the box [lo, hi], down to boxes of a quarter voxel: below
// `threshold` returns true (some point in the box is that close to a surface).
bool box_touches(const octofuse::sim::Scene& scene, const Eigen::Vector3d& lo,
                 const Eigen::Vector3d& hi, double threshold, double voxel, int depth = 0) {
  const Eigen::Vector3d c = 0.5 * (lo + hi);
  const double h = 0.5 * (hi - lo).norm();
  const double d = scene.distance_m(c);
  if (d <= threshold) return true;
  if (d > h + threshold) return false;
  if (h < 0.25 * voxel || depth > 12) return false;
  const Eigen::Vector3d half = 0.5 * (hi - lo);
  for (int k = 0; k < 8; ++k) {
    const Eigen::Vector3d o((k & 1) ? half.x() : 0.0, (k & 2) ? half.y() : 0.0,
                            (k & 4) ? half.z() : 0.0);
    if (box_touches(scene, lo + o, lo + o + half, threshold, voxel, depth + 1)) return true;
  }
  return false;
}

// The least exact distance along the segment, sampled every quarter voxel.
double segment_distance(const octofuse::sim::Scene& scene, const Eigen::Vector3d& a,
                        const Eigen::Vector3d& b, double voxel) {
  const double length = (b - a).norm();
  const int steps = std::max(1, static_cast<int>(std::ceil(length / (0.25 * voxel))));
  double best = 1e9;
  for (int i = 0; i <= steps; ++i) {
    best = std::min(best, scene.distance_m(a + (b - a) * (static_cast<double>(i) / steps)));
  }
  return best;
}

int run_scene(const std::string& name, long frames, long sample_points, float voxel_m, int threads,
              int finest_octant, bool exact, Figures* f) {
  const std::string spec = "sim:" + name;
  octofuse::ErrorText error;
  std::unique_ptr<octofuse::sim::SimSource> truth = octofuse::sim::make_sim_source(
      (spec + (frames > 0 ? ",frames=" + std::to_string(frames) : std::string())).c_str(), &error);
  if (truth == nullptr || !truth->open().ok()) return octofuse::cli::fail("cannot open " + spec);
  const octofuse::sim::Scene& scene = truth->scene();
  const int frame_count = truth->frame_count();
  const octofuse::PinholeCamera camera = truth->intrinsics();

  RunOptions options;
  options.source_spec = spec;
  options.voxel_size_m = voxel_m;
  options.threads = threads;
  options.progress = false;
  options.write_mesh = false;
  if (frames > 0) {
    options.max_frames = frames;
    options.source.frames = frames;
  }
  const double voxel = voxel_m;
  options.free_space_exact = exact;
  options.adjust_config = [finest_octant](octofuse::PipelineConfig* c) {
    c->free_space.finest_octant_voxels = finest_octant;
  };
  options.inspect_final_map = [&](const MapQuery<MultiresVoxel>& query) {
    const auto& map = query.map();
    const Eigen::Vector3d origin = map.config().origin_W.cast<double>();
    const double side = map.config().size_m();
    const double mu = query.mu_m();
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    // Camera centres and world-to-camera rotations, every second frame.
    std::vector<octofuse::Se3d> T_C_W;
    for (int i = 0; i < frame_count; i += 2) {
      T_C_W.push_back(truth->ground_truth_T_W_C(i).inverse());
    }
    auto in_view = [&](const Eigen::Vector3d& p_W) {
      return octofuse::examples::seen_through(scene, T_C_W, camera, p_W);
    };
    for (long i = 0; i < sample_points; ++i) {
      const Eigen::Vector3d p_W = origin + side * Eigen::Vector3d(unit(rng), unit(rng), unit(rng));
      const octofuse::PointAnswer a = query.point(p_W.cast<float>()).value();
      const double sdf = scene.distance_m(p_W);
      ++f->points;
      if (a.state == PointState::free) {
        ++f->reported_free;
        if (sdf <= voxel) {
          ++f->unsafe_points;
          const octofuse::FreeOctant o =
              query.free_space() != nullptr
                  ? query.free_space()->find(map.point_to_voxel(p_W.cast<float>()))
                  : octofuse::FreeOctant();
          const auto* block = map.find_block_at_voxel(map.point_to_voxel(p_W.cast<float>()));
          std::fprintf(stderr,
                       "unsafe: %.4f %.4f %.4f exact distance %.4f m, free octant %d (level %d, "
                       "frame %u), block %d (frame %u), bound %.4f m\n",
                       p_W.x(), p_W.y(), p_W.z(), sdf, o.free, o.level, o.free_frame,
                       block != nullptr, block != nullptr ? block->last_updated_frame : 0u,
                       static_cast<double>(a.distance_m));
        }
        const double over = static_cast<double>(a.distance_m) - sdf;
        f->free_distance_sum += static_cast<double>(a.distance_m);
        f->free_exact_sum += sdf;
        f->worst_over_bound = std::max(f->worst_over_bound, over);
        if (over > 0.01) {
          if (f->over_bound_points < 20) {
            const octofuse::FreeOctant o =
                query.free_space() != nullptr
                    ? query.free_space()->find(map.point_to_voxel(p_W.cast<float>()))
                    : octofuse::FreeOctant();
            std::fprintf(stderr,
                         "over bound: %.4f %.4f %.4f exact distance %.4f m, reported %.4f m, "
                         "free octant level %d side %d voxels (frame %u)\n",
                         p_W.x(), p_W.y(), p_W.z(), sdf, static_cast<double>(a.distance_m), o.level,
                         o.size_voxels, o.free_frame);
          }
          ++f->over_bound_points;
        }
      }
      if (a.state == PointState::near && std::abs(sdf) < mu) {
        ++f->near_points;
        const double e = static_cast<double>(a.distance_m) - sdf;
        f->near_sq_error += e * e;
        f->near_abs_error.push_back(std::abs(e));
        if (std::abs(sdf) < 3.0 * voxel) {
          ++f->close_points;
          f->close_sq_error += e * e;
        }
      }
      if (sdf > voxel && in_view(p_W)) {
        ++f->truly_free_in_view;
        if (a.state == PointState::free) ++f->truly_free_in_view_reported_free;
        ++f->missed[static_cast<int>(a.state)];
        if (a.state == PointState::unknown) {
          const int bucket = sdf < 0.1 ? 0 : sdf < 0.2 ? 1 : sdf < 0.4 ? 2 : sdf < 0.8 ? 3 : 4;
          ++f->unknown_by_distance[bucket];
        }

        if (a.state == PointState::free || (a.state == PointState::near && a.distance_m > 0.0f)) {
          ++f->truly_free_in_view_free_or_near;
        }
      }
    }
    // Regions near the camera path: centres within 2 m of a random frame's camera, in view.
    std::vector<double> point_us, box_us, swept_us;
    auto near_path = [&]() {
      const octofuse::Se3d T_W_C =
          truth->ground_truth_T_W_C(static_cast<int>(unit(rng) * (frame_count - 1)));
      const Eigen::Vector3d p_C((unit(rng) - 0.5) * 2.0, (unit(rng) - 0.5) * 1.5,
                                0.5 + 2.0 * unit(rng));
      return T_W_C * p_C;
    };
    using clock = std::chrono::steady_clock;
    for (int i = 0; i < 20000; ++i) {
      const Eigen::Vector3d c = near_path();
      const auto t0 = clock::now();
      const octofuse::PointAnswer pa = query.point(c.cast<float>()).value();
      const auto t1 = clock::now();
      (void)pa;
      point_us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());

      const Eigen::Vector3d half = Eigen::Vector3d::Constant(0.25);
      const auto t2 = clock::now();
      const octofuse::RegionAnswer box =
          query.box((c - half).cast<float>(), (c + half).cast<float>()).value();
      const auto t3 = clock::now();
      box_us.push_back(std::chrono::duration<double, std::micro>(t3 - t2).count());
      f->box_max_visits = std::max(f->box_max_visits, box.visits);
      ++f->regions;
      if (box.state == RegionState::free) {
        ++f->regions_free;
        if (box_touches(scene, c - half, c + half, voxel, voxel)) ++f->unsafe_regions;
      }

      const double angle = 6.283185307 * unit(rng);
      const double elevation = (unit(rng) - 0.5) * 1.0;
      const Eigen::Vector3d dir(std::cos(angle) * std::cos(elevation),
                                std::sin(angle) * std::cos(elevation), std::sin(elevation));
      const Eigen::Vector3d end = c + dir;
      const auto t4 = clock::now();
      const octofuse::RegionAnswer swept =
          query.swept_sphere(c.cast<float>(), end.cast<float>(), 0.3f).value();
      const auto t5 = clock::now();
      swept_us.push_back(std::chrono::duration<double, std::micro>(t5 - t4).count());
      f->swept_max_visits = std::max(f->swept_max_visits, swept.visits);
      ++f->regions;
      if (swept.state == RegionState::free) {
        ++f->regions_free;
        if (segment_distance(scene, c, end, voxel) <= 0.3 + voxel) ++f->unsafe_regions;
      }
    }
    const auto p = percentiles(point_us);
    const auto b = percentiles(box_us);
    const auto s = percentiles(swept_us);
    f->point_us[0] = p.median;
    f->point_us[1] = p.p99;
    f->box_us[0] = b.median;
    f->box_us[1] = b.p99;
    f->swept_us[0] = s.median;
    f->swept_us[1] = s.p99;
  };
  RunSummary on;
  int rc = octofuse::examples::run_pipeline(options, &on);
  if (rc != 0) return rc;
  options.inspect_final_map = nullptr;
  options.free_space = false;
  RunSummary off;
  rc = octofuse::examples::run_pipeline(options, &off);
  if (rc != 0) return rc;
  std::vector<double> total_on, total_off, free_ms;
  for (const auto& s : on.frames) {
    total_on.push_back(s.times.total_ms);
    free_ms.push_back(s.times.free_space_ms);
  }
  for (const auto& s : off.frames) total_off.push_back(s.times.total_ms);
  f->ms_total_on = percentiles(total_on).median;
  f->ms_total_off = percentiles(total_off).median;
  f->ms_free_space = percentiles(free_ms).median;
  f->map_mb_on = static_cast<double>(on.map_memory.bytes_used) / 1048576.0;
  f->map_mb_off = static_cast<double>(off.map_memory.bytes_used) / 1048576.0;
  f->free_mb = static_cast<double>(on.free_space_bytes) / 1048576.0;
  return 0;
}

// What the command line sets.
struct QueryBenchArgs {
  std::vector<std::string> scenes = {"desk", "room"};
  long frames = 0;
  long points = 1000000;
  double voxel = 0.01;
  std::int64_t threads = 1;
  std::int64_t finest_octant = 0;
  bool exact = false;
};

using Option = octofuse::cli::Option<QueryBenchArgs>;

const Option kOptions[] = {
    {"--scenes", "LIST", "sim scenes, comma separated: desk, room (default desk,room)",
     [](QueryBenchArgs& a, const std::string& list) {
       a.scenes.clear();
       std::size_t start = 0;
       while (start <= list.size()) {
         const std::size_t comma = list.find(',', start);
         const std::string name =
             list.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
         if (name != "desk" && name != "room") return "--scenes: unknown scene '" + name + "'";
         a.scenes.push_back(name);
         if (comma == std::string::npos) break;
         start = comma + 1;
       }
       return std::string();
     }},
    {"--frames", "N", "frames per run (default: the scene's whole sequence)",
     [](QueryBenchArgs& a, const std::string& v) {
       std::int64_t n = 0;
       if (!octofuse::cli::parse_int(v, 1, 100000, n)) {
         return std::string("--frames needs a count in [1, 100000]");
       }
       a.frames = static_cast<long>(n);
       return std::string();
     }},
    {"--points", "N", "random points for safety and coverage (default 1000000)",
     [](QueryBenchArgs& a, const std::string& v) {
       std::int64_t n = 0;
       if (!octofuse::cli::parse_int(v, 1, 100000000, n)) {
         return std::string("--points needs a count in [1, 1e8]");
       }
       a.points = static_cast<long>(n);
       return std::string();
     }},
    {"--voxel-size", "M", "finest voxel edge in metres, in [0.001, 0.1] (default 0.01)",
     [](QueryBenchArgs& a, const std::string& v) {
       if (!octofuse::cli::parse_double(v, 1e-3, 0.1, a.voxel)) {
         return std::string("--voxel-size needs metres in [0.001, 0.1]");
       }
       return std::string();
     }},
    {"--finest-octant", "V",
     "the finest free-space octant's edge in voxels: 2, 4, 8, 16, 32 or 64\n"
     "(default 0: automatic)",
     [](QueryBenchArgs& a, const std::string& v) {
       if (!octofuse::cli::parse_int(v, 0, 64, a.finest_octant) ||
           (a.finest_octant & (a.finest_octant - 1)) != 0 || a.finest_octant == 1) {
         return std::string("--finest-octant needs 0 (automatic), 2, 4, 8, 16, 32 or 64 (voxels)");
       }
       return std::string();
     }},
    {"--free-space-exact", nullptr,
     "settle octants beside nearer objects' silhouettes pixel by pixel\n"
     "(octofuse-replay's --free-space-exact)",
     [](QueryBenchArgs& a, const std::string&) {
       a.exact = true;
       return std::string();
     }},
    {"--threads", "N", "worker threads, in [1, 64] (default 1)",
     [](QueryBenchArgs& a, const std::string& v) {
       if (!octofuse::cli::parse_int(v, 1, 64, a.threads)) {
         return std::string("--threads needs a count in [1, 64]");
       }
       return std::string();
     }},
};

}  // namespace

int main(int argc, char** argv) {
  QueryBenchArgs args;
  std::string error;
  switch (octofuse::cli::parse_options(argc, argv, 1, kOptions, "unknown option ", &args, &error)) {
    case octofuse::cli::Parsed::help:
      std::printf("usage: octofuse-query-bench [options]\n\n%s",
                  octofuse::cli::options_usage(kOptions).c_str());
      return 0;
    case octofuse::cli::Parsed::error:
      return octofuse::cli::fail(error);
    case octofuse::cli::Parsed::options:
      break;
  }
  const std::vector<std::string>& scenes = args.scenes;
  const long frames = args.frames;
  const long points = args.points;
  const double voxel = args.voxel;
  const std::int64_t threads = args.threads;
  const std::int64_t finest_octant = args.finest_octant;
  const bool exact = args.exact;
  std::printf(
      "| scene | points | unsafe free points | unsafe free regions (of free / asked) | free of "
      "truly free in view | free or near > 0 | near SDF RMSE mm (points), within mu; within 3 "
      "voxels | point us med/p99 | box 0.5 m "
      "us med/p99 (max visits) | swept 0.3 m x 1 m us med/p99 (max visits) | frame ms on/off "
      "(free-space stage) | map MB off / on + free space |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  for (const std::string& name : scenes) {
    Figures f;
    const int rc = run_scene(name, frames, points, static_cast<float>(voxel),
                             static_cast<int>(threads), static_cast<int>(finest_octant), exact, &f);
    if (rc != 0) return rc;
    const double share = f.truly_free_in_view > 0
                             ? static_cast<double>(f.truly_free_in_view_reported_free) /
                                   static_cast<double>(f.truly_free_in_view)
                             : 0.0;
    const double share_near = f.truly_free_in_view > 0
                                  ? static_cast<double>(f.truly_free_in_view_free_or_near) /
                                        static_cast<double>(f.truly_free_in_view)
                                  : 0.0;
    const double rmse =
        f.near_points > 0 ? std::sqrt(f.near_sq_error / static_cast<double>(f.near_points)) : 0.0;
    const double close_rmse =
        f.close_points > 0 ? std::sqrt(f.close_sq_error / static_cast<double>(f.close_points))
                           : 0.0;
    std::printf(
        "| sim:%s | %ld (%ld free) | %ld | %ld (of %ld / %ld) | %.3f (%ld) | %.3f | %.2f (%ld); "
        "%.2f (%ld) | "
        "%.2f / %.2f | %.1f / %.1f (%u) | %.1f / %.1f (%u) | %.1f / %.1f (%.2f) | %.1f / %.1f + "
        "%.2f |\n",
        name.c_str(), f.points, f.reported_free, f.unsafe_points, f.unsafe_regions, f.regions_free,
        f.regions, share, f.truly_free_in_view, share_near, rmse * 1000.0, f.near_points,
        close_rmse * 1000.0, f.close_points, f.point_us[0], f.point_us[1], f.box_us[0], f.box_us[1],
        f.box_max_visits, f.swept_us[0], f.swept_us[1], f.swept_max_visits, f.ms_total_on,
        f.ms_total_off, f.ms_free_space, f.map_mb_off, f.map_mb_on, f.free_mb);
    const octofuse::examples::Percentiles near_error = percentiles(f.near_abs_error);
    std::printf(
        "  sim:%s near points within mu, |signed-distance error| median / p90 / p99: %.1f / "
        "%.1f / %.1f mm\n",
        name.c_str(), near_error.median * 1000.0, near_error.p90 * 1000.0, near_error.p99 * 1000.0);
    std::printf(
        "  sim:%s free points whose distance exceeds the exact one by more than 1 cm: %ld (of %ld; "
        "worst excess %.1f mm); mean distance reported %.1f mm, exact %.1f mm\n",
        name.c_str(), f.over_bound_points, f.reported_free, f.worst_over_bound * 1000.0,
        f.reported_free > 0 ? f.free_distance_sum * 1000.0 / static_cast<double>(f.reported_free)
                            : 0.0,
        f.reported_free > 0 ? f.free_exact_sum * 1000.0 / static_cast<double>(f.reported_free)
                            : 0.0);
    std::printf(
        "  sim:%s truly free in view, as reported: outside %ld, unknown %ld, free %ld, near %ld, "
        "inside %ld\n",
        name.c_str(), f.missed[0], f.missed[1], f.missed[2], f.missed[3], f.missed[4]);
    std::printf(
        "  sim:%s of them unknown, by distance to the nearest surface: < 0.1 m %ld, 0.1-0.2 m %ld, "
        "0.2-0.4 m %ld, 0.4-0.8 m %ld, beyond %ld\n",
        name.c_str(), f.unknown_by_distance[0], f.unknown_by_distance[1], f.unknown_by_distance[2],
        f.unknown_by_distance[3], f.unknown_by_distance[4]);
    std::fflush(stdout);
  }
  return 0;
}
