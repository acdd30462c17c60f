// octofuse-plan: a planner on the distance field (query/esdf.hpp), and the field's figures.
//
//   octofuse-plan --scene room [--voxel 0.02] [--frames N] [--plan] [--points N]
//
// Maps a sim scene (ground-truth poses) with the distance field on. With --plan, every
// --replan-every frames it plans a path for a sphere of --radius metres from --start to --goal
// through space the map knows to be free (A* over a lattice; a point is usable when the map reads
// it free and the field, with unknown space as obstacle, bounds its distance from everything by
// the radius), and at the end checks the path against the scene's exact distance and compares it
// with the shortest path over the same lattice in the exact scene. With --points N it compares
// the final field with the exact distance at N random points of its window: unsafe answers,
// RMSE, coverage, update cost, memory and the time of a batch of 10 000 queries.
// Exit status: 0 when the checks asked for pass, 1 when one fails, 2 on a bad command line.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <queue>
#include <random>
#include <string>
#include <vector>

#include "cli.hpp"
#include "octofuse/map/interpolation.hpp"
#include "octofuse/pipeline/mapper.hpp"
#include "octofuse/pipeline/steady_clock.hpp"
#include "octofuse/ports/sim/sim_source.hpp"
#include "sim_visibility.hpp"

using namespace octofuse;

namespace {

struct Options {
  std::string scene = "room";
  float voxel_m = 0.02f;
  int frames = 0;
  bool plan = false;
  long points = 0;
  float radius_m = 0.3f;
  // Across the room's table, over the lamp, inside the camera's orbit.
  Eigen::Vector3f start_W = Eigen::Vector3f(0.9f, -0.9f, 1.4f);
  Eigen::Vector3f goal_W = Eigen::Vector3f(-0.9f, 0.9f, 1.4f);
  int replan_every = 30;
  float lattice_m = 0.08f;
  std::uint32_t budget = 1u << 18;
  bool unknown_obstacle = false;
  int cells = 128;
  int cell_voxels = 2;    // the field's cell edge in finest voxels (EsdfConfig::cell_voxels)
  int show_unsafe = 0;    // print the first N unsafe points with what the map holds around them
  float follow_m = 0.0f;  // > 0: the window follows the camera (EsdfConfig::follow_m)
};

// Strict numbers (the whole token, finite, in range): a typo is an error, not a silent zero.
template <typename T>
bool number(const char* text, double min, double max, T* out) {
  double v = 0.0;
  if (!cli::parse_double(text, min, max, v)) return false;
  *out = static_cast<T>(v);
  return true;
}

template <typename T>
bool integer(const char* text, std::int64_t min, std::int64_t max, T* out) {
  std::int64_t v = 0;
  if (!cli::parse_int(text, min, max, v)) return false;
  *out = static_cast<T>(v);
  return true;
}

int usage(const char* why) {
  std::fprintf(stderr,
               "error: %s\nusage: octofuse-plan [--scene desk|room] [--voxel M] [--frames N] "
               "[--cells N] [--cell-voxels 1|2|4|8] [--budget CELLS] [--follow M] "
               "[--unknown-obstacle] [--plan [--start "
               "X,Y,Z] [--goal "
               "X,Y,Z] [--radius M] "
               "[--replan-every N] [--lattice M]] [--points N [--show-unsafe N]]\n",
               why);
  return 2;
}

bool parse_point(const char* text, Eigen::Vector3f* out) {
  float x = 0, y = 0, z = 0;
  char tail = 0;
  if (std::sscanf(text, "%f,%f,%f%c", &x, &y, &z, &tail) != 3) return false;
  *out = Eigen::Vector3f(x, y, z);
  return std::isfinite(x) && std::isfinite(y) && std::isfinite(z);
}

// A* over a cubic lattice of `step_m` inside [lo, hi], 26 neighbours; usable(p) says whether a
// node or an edge sample may be occupied by the sphere's centre. Returns the path (empty: none).
template <typename Usable>
std::vector<Eigen::Vector3f> plan_path(const Eigen::Vector3f& window_lo, const Eigen::Vector3f& hi,
                                       float step_m, const Eigen::Vector3f& start,
                                       const Eigen::Vector3f& goal, const Usable& usable) {
  // The lattice passes through the start.
  const Eigen::Vector3f lo =
      start - ((start - window_lo) / step_m).array().floor().matrix() * step_m;
  const Eigen::Vector3i size = ((hi - lo) / step_m).cast<int>() + Eigen::Vector3i::Ones();
  const long count = static_cast<long>(size.x()) * size.y() * size.z();
  auto index_of = [&](const Eigen::Vector3i& c) {
    return (static_cast<long>(c.z()) * size.y() + c.y()) * size.x() + c.x();
  };
  auto cell_of = [&](const Eigen::Vector3f& p) {
    return ((p - lo) / step_m).array().round().cast<int>().matrix().eval();
  };
  auto point_of = [&](const Eigen::Vector3i& c) { return (lo + c.cast<float>() * step_m).eval(); };
  const Eigen::Vector3i s = cell_of(start);
  const Eigen::Vector3i g = cell_of(goal);
  for (int a = 0; a < 3; ++a) {
    if (s[a] < 0 || g[a] < 0 || s[a] >= size[a] || g[a] >= size[a]) return {};
  }
  // 0 unknown, 1 usable, 2 not.
  std::vector<std::uint8_t> state(static_cast<std::size_t>(count), 0);
  auto node_ok = [&](const Eigen::Vector3i& c) {
    std::uint8_t& st = state[static_cast<std::size_t>(index_of(c))];
    if (st == 0) st = usable(point_of(c)) ? 1 : 2;
    return st == 1;
  };
  if (!node_ok(s) || !node_ok(g)) return {};
  std::vector<float> cost(static_cast<std::size_t>(count), 1e30f);
  std::vector<long> parent(static_cast<std::size_t>(count), -1);
  using Entry = std::pair<float, long>;
  std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> open;
  cost[static_cast<std::size_t>(index_of(s))] = 0.0f;
  open.push({(point_of(g) - point_of(s)).norm(), index_of(s)});
  const long goal_index = index_of(g);
  while (!open.empty()) {
    const Entry e = open.top();
    open.pop();
    const long i = e.second;
    if (i == goal_index) break;
    const Eigen::Vector3i c(static_cast<int>(i % size.x()),
                            static_cast<int>((i / size.x()) % size.y()),
                            static_cast<int>(i / (static_cast<long>(size.x()) * size.y())));
    const float here = cost[static_cast<std::size_t>(i)];
    if (e.first > here + (point_of(g) - point_of(c)).norm() + 1e-4f) continue;  // stale
    for (int dz = -1; dz <= 1; ++dz) {
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          if (dx == 0 && dy == 0 && dz == 0) continue;
          const Eigen::Vector3i n = c + Eigen::Vector3i(dx, dy, dz);
          if ((n.array() < 0).any() || (n.array() >= size.array()).any()) continue;
          if (!node_ok(n)) continue;
          // The edge's middle too (the nodes' margins cover the rest).
          if (!usable(0.5f * (point_of(c) + point_of(n)))) continue;
          const float step = (point_of(n) - point_of(c)).norm();
          const long ni = index_of(n);
          if (here + step < cost[static_cast<std::size_t>(ni)]) {
            cost[static_cast<std::size_t>(ni)] = here + step;
            parent[static_cast<std::size_t>(ni)] = i;
            open.push({here + step + (point_of(g) - point_of(n)).norm(), ni});
          }
        }
      }
    }
  }
  if (parent[static_cast<std::size_t>(goal_index)] < 0) return {};
  std::vector<Eigen::Vector3f> path;
  for (long i = goal_index; i >= 0; i = parent[static_cast<std::size_t>(i)]) {
    path.push_back(point_of(
        Eigen::Vector3i(static_cast<int>(i % size.x()), static_cast<int>((i / size.x()) % size.y()),
                        static_cast<int>(i / (static_cast<long>(size.x()) * size.y())))));
  }
  std::reverse(path.begin(), path.end());
  return path;
}

double path_length(const std::vector<Eigen::Vector3f>& path) {
  double sum = 0.0;
  for (std::size_t i = 1; i < path.size(); ++i) sum += (path[i] - path[i - 1]).norm();
  return sum;
}

// The least exact distance along the path, sampled every centimetre.
double path_clearance(const sim::Scene& scene, const std::vector<Eigen::Vector3f>& path) {
  double best = 1e9;
  for (std::size_t i = 1; i < path.size(); ++i) {
    const Eigen::Vector3d a = path[i - 1].cast<double>();
    const Eigen::Vector3d b = path[i].cast<double>();
    const int steps = std::max(1, static_cast<int>(std::ceil((b - a).norm() / 0.01)));
    for (int k = 0; k <= steps; ++k) {
      best = std::min(best, scene.distance_m(a + (b - a) * (static_cast<double>(k) / steps)));
    }
  }
  return best;
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const std::size_t i = static_cast<std::size_t>(q * static_cast<double>(v.size() - 1) + 0.5);
  return v[std::min(i, v.size() - 1)];
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    const bool has_value = i + 1 < argc;
    auto value = [&]() { return argv[++i]; };
    if (arg == "--plan") {
      o.plan = true;
    } else if (arg == "--unknown-obstacle") {
      o.unknown_obstacle = true;
    } else if (!has_value) {
      return usage(("unknown option or missing value: " + arg).c_str());
    } else if (arg == "--scene") {
      o.scene = value();
      if (o.scene != "desk" && o.scene != "room") return usage("--scene is desk or room");
    } else if (arg == "--voxel") {
      if (!number(value(), 0.005, 0.1, &o.voxel_m)) return usage("--voxel in [0.005, 0.1]");
    } else if (arg == "--frames") {
      if (!integer(value(), 1, 1000000, &o.frames)) return usage("--frames in [1, 1000000]");
    } else if (arg == "--points") {
      if (!integer(value(), 1, 100000000, &o.points)) return usage("--points in [1, 100000000]");
    } else if (arg == "--radius") {
      if (!number(value(), 0.0, 2.0, &o.radius_m) || !(o.radius_m > 0.0f && o.radius_m < 2.0f)) {
        return usage("--radius in (0, 2)");
      }
    } else if (arg == "--start") {
      if (!parse_point(value(), &o.start_W)) return usage("--start X,Y,Z");
    } else if (arg == "--goal") {
      if (!parse_point(value(), &o.goal_W)) return usage("--goal X,Y,Z");
    } else if (arg == "--replan-every") {
      if (!integer(value(), 1, 1000000, &o.replan_every)) {
        return usage("--replan-every in [1, 1000000]");
      }
    } else if (arg == "--lattice") {
      if (!number(value(), 0.02, 0.5, &o.lattice_m)) return usage("--lattice in [0.02, 0.5]");
    } else if (arg == "--budget") {
      if (!integer(value(), 0, 0xffffffffLL, &o.budget)) {
        return usage("--budget in [0, 4294967295] (0: unbounded)");
      }
    } else if (arg == "--cells") {
      if (!integer(value(), 8, 1016, &o.cells) || o.cells % 8 != 0) {
        return usage("--cells is a multiple of 8 in [8, 1016]");
      }
    } else if (arg == "--cell-voxels") {
      if (!integer(value(), 1, 8, &o.cell_voxels) ||
          (o.cell_voxels != 1 && o.cell_voxels != 2 && o.cell_voxels != 4 && o.cell_voxels != 8)) {
        return usage("--cell-voxels is 1, 2, 4 or 8");
      }
    } else if (arg == "--follow") {
      if (!number(value(), 0.0, 100.0, &o.follow_m) || !(o.follow_m > 0.0f)) {
        return usage("--follow in (0, 100]");
      }
    } else if (arg == "--show-unsafe") {
      if (!integer(value(), 0, 1000000, &o.show_unsafe))
        return usage("--show-unsafe in [0, 1000000]");
    } else {
      return usage(("unknown option: " + arg).c_str());
    }
  }

  ErrorText error;
  const std::string spec =
      "sim:" + o.scene + (o.frames > 0 ? ",frames=" + std::to_string(o.frames) : std::string());
  std::unique_ptr<sim::SimSource> source = sim::make_sim_source(spec.c_str(), &error);
  if (source == nullptr || !source->open().ok()) {
    std::fprintf(stderr, "error: cannot open %s\n", spec.c_str());
    return 1;
  }
  const sim::Scene& scene = source->scene();

  MapperSettings settings;
  settings.voxel_size_m = o.voxel_m;
  settings.map_size_m = o.scene == "room" ? 8.0f : 5.12f;
  settings.max_blocks = o.voxel_m < 0.015f ? 200000 : 60000;
  settings.first_T_W_C = source->ground_truth_T_W_C(0);
  settings.mesh_vertex_capacity = 0;
  PipelineConfig config = pipeline_config(source->intrinsics(), settings);
  config.pose_source = PoseSource::ground_truth;
  // The window over the scene's middle: the room's centre, or the desk the camera looks at.
  config.esdf.enabled = true;
  config.esdf.cells_per_side = std::min(o.cells, config.map.voxels_per_side() / 2);
  config.esdf.cell_voxels = o.cell_voxels;
  config.esdf.centre_W =
      o.scene == "room"
          ? Eigen::Vector3f(0.0f, 0.0f, 1.35f)
          : config.map.origin_W + Eigen::Vector3f::Constant(0.5f * config.map.size_m());
  config.esdf.max_cell_steps = o.budget;
  // The planner keeps the sphere out of unknown space too.
  config.esdf.unknown_is_obstacle = o.unknown_obstacle;
  config.esdf.follow_m = o.follow_m;
  const std::size_t bytes_with = bytes_required(config);
  PipelineConfig without = config;
  without.esdf.enabled = false;
  const std::size_t bytes_without = bytes_required(without);
  Mapper<> mapper;
  if (!mapper.init(config, 0, 0, steady_clock()).ok()) {
    std::fprintf(stderr, "error: %s\n", mapper.last_error());
    return 1;
  }
  const Pipeline<MultiresVoxel>& pipeline = mapper.pipeline();
  const EsdfField& field = pipeline.esdf();
  std::printf(
      "scene %s, %.3f m voxels, field window %d^3 cells of %.3f m (%.2f m), error bound "
      "%.3f m, field memory %.1f MB = %.1f %% of the pipeline's %.1f MB\n",
      o.scene.c_str(), static_cast<double>(o.voxel_m), field.cells_per_side(),
      static_cast<double>(field.cell_m()),
      static_cast<double>(field.cell_m() * field.cells_per_side()),
      static_cast<double>(field.error_bound_m()),
      static_cast<double>(bytes_with - bytes_without) / 1e6,
      100.0 * static_cast<double>(bytes_with - bytes_without) / static_cast<double>(bytes_without),
      static_cast<double>(bytes_without) / 1e6);

  const MapQuery<MultiresVoxel> query = mapper.query();
  auto usable = [&](const Eigen::Vector3f& p) {
    const Result<PointAnswer> a = query.point(p);
    if (!a.ok() || a.value().state != PointState::free) return false;
    const Result<EsdfAnswer> d = field.distance(p);
    // Edges are checked at their middles: a node or middle needs half a lattice diagonal's
    // quarter more (the distance changes by at most the distance moved).
    return d.ok() && d.value().has_distance &&
           d.value().lower_bound_m >= o.radius_m + 0.25f * o.lattice_m * 1.7320508f;
  };
  // The published window (it moves with --follow).
  Eigen::Vector3f lo, hi;
  auto read_window = [&]() {
    lo = field.window_min_W();
    hi = lo + Eigen::Vector3f::Constant(field.cell_m() * field.cells_per_side());
  };
  read_window();
  std::vector<Eigen::Vector3f> path;

  DepthFrame frame;
  FrameStats stats;
  int frames = 0;
  double total_ms = 0.0, esdf_ms = 0.0;
  std::uint64_t esdf_steps = 0;
  int published = 0, budget_hits = 0;
  while (source->next(frame).outcome == FrameOutcome::frame) {
    const Status status = mapper.process(frame, &stats);
    if (!status.ok() && stats.result != FrameResult::lost) {
      std::fprintf(stderr, "error: %s\n", mapper.last_error());
      return 1;
    }
    ++frames;
    total_ms += stats.times.total_ms;
    esdf_ms += stats.times.esdf_ms;
    esdf_steps += stats.esdf.cell_steps;
    published += stats.esdf.published ? 1 : 0;
    budget_hits += stats.esdf.budget_hit ? 1 : 0;
    read_window();
    if (o.plan && frames % o.replan_every == 0) {
      path = plan_path(lo, hi, o.lattice_m, o.start_W, o.goal_W, usable);
      std::printf("frame %d: field of map version %llu, path %s (%zu nodes, %.2f m)\n", frames,
                  static_cast<unsigned long long>(field.published_version()),
                  path.empty() ? "none yet" : "found", path.size(), path_length(path));
    }
  }
  std::printf(
      "%d frames: %.2f ms a frame, field update %.2f ms (%.1f %%), %.0f cells a frame, "
      "%d fields published, budget hit in %d frames\n",
      frames, total_ms / frames, esdf_ms / frames, 100.0 * esdf_ms / total_ms,
      static_cast<double>(esdf_steps) / frames, published, budget_hits);
  mapper.pipeline().flush_esdf();
  read_window();
  if (o.follow_m > 0.0f) {
    std::printf("window [%.2f %.2f %.2f] to [%.2f %.2f %.2f], the camera at %.2f %.2f %.2f\n",
                static_cast<double>(lo.x()), static_cast<double>(lo.y()),
                static_cast<double>(lo.z()), static_cast<double>(hi.x()),
                static_cast<double>(hi.y()), static_cast<double>(hi.z()),
                stats.T_W_C.translation().x(), stats.T_W_C.translation().y(),
                stats.T_W_C.translation().z());
  }
  const MapMemory memory = pipeline.map().memory();
  std::printf("map: %u blocks, %.1f MB in use; the field's %.1f MB are %.1f %% of that\n",
              memory.blocks_used, static_cast<double>(memory.bytes_used) / 1e6,
              static_cast<double>(bytes_with - bytes_without) / 1e6,
              100.0 * static_cast<double>(bytes_with - bytes_without) /
                  static_cast<double>(memory.bytes_used));

  int rc = 0;
  if (o.plan) {
    path = plan_path(lo, hi, o.lattice_m, o.start_W, o.goal_W, usable);
    const float margin = 0.25f * o.lattice_m * 1.7320508f;
    const std::vector<Eigen::Vector3f> best =
        plan_path(lo, hi, o.lattice_m, o.start_W, o.goal_W, [&](const Eigen::Vector3f& p) {
          return scene.distance_m(p.cast<double>()) >= o.radius_m + margin;
        });
    if (path.empty()) {
      std::printf("final: no path through known free space\n");
      for (const Eigen::Vector3f& p : {o.start_W, o.goal_W}) {
        const PointAnswer a = query.point(p).value();
        const EsdfAnswer d = field.distance(p).value();
        std::printf("  %.2f %.2f %.2f: %s, field lower bound %.3f m\n", static_cast<double>(p.x()),
                    static_cast<double>(p.y()), static_cast<double>(p.z()),
                    point_state_name(a.state), static_cast<double>(d.lower_bound_m));
      }
      rc = 1;
    } else {
      const double clearance = path_clearance(scene, path);
      const double ratio = best.empty() ? 0.0 : path_length(path) / path_length(best);
      std::printf(
          "final path, %zu nodes, %.2f m; least exact distance to a surface %.3f m "
          "(radius %.2f); shortest over the lattice in the exact scene %.2f m: %.2fx\n",
          path.size(), path_length(path), clearance, static_cast<double>(o.radius_m),
          path_length(best), ratio);
      for (const Eigen::Vector3f& p : path) {
        std::printf("  %.3f %.3f %.3f\n", static_cast<double>(p.x()), static_cast<double>(p.y()),
                    static_cast<double>(p.z()));
      }
      if (clearance < o.radius_m) rc = 1;
    }
  }

  if (o.points > 0) {
    const float voxel = o.voxel_m;
    const float mu = config.fusion.mu_m;
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<float> unit(0.0f, 1.0f);
    std::vector<Se3d> T_C_W;
    for (int i = 0; i < source->frame_count(); i += 10) {
      T_C_W.push_back(source->ground_truth_T_W_C(i).inverse());
    }
    const PinholeCamera camera = source->intrinsics();
    auto in_view = [&](const Eigen::Vector3d& p_W) {
      return examples::seen_through(scene, T_C_W, camera, p_W);
    };
    // Whether the map observed the scene's surface point nearest to p (a few projection steps
    // along the exact distance's gradient).
    auto nearest_surface_point = [&](const Eigen::Vector3f& p) {
      Eigen::Vector3d q = p.cast<double>();
      for (int it = 0; it < 4; ++it) {
        const double d0 = scene.distance_m(q);
        Eigen::Vector3d g;
        for (int k = 0; k < 3; ++k) {
          Eigen::Vector3d h = Eigen::Vector3d::Zero();
          h[k] = 1e-4;
          g[k] = (scene.distance_m(q + h) - d0) / 1e-4;
        }
        if (!(g.norm() > 0.5)) break;
        q -= d0 * g.normalized();
      }
      return q;
    };
    auto nearest_surface_seen = [&](const Eigen::Vector3f& p) {
      const Eigen::Vector3d q = nearest_surface_point(p);
      // ... and inside the field's window (beyond it the field caps its distances).
      if ((q.cast<float>().array() < lo.array()).any() ||
          (q.cast<float>().array() > hi.array()).any()) {
        return false;
      }
      const PointState s = query.point(q.cast<float>()).value().state;
      return s == PointState::near || s == PointState::inside;
    };
    // The field stops at its window's faces inside the map's cube (surfaces beyond are not in it)
    // and caps its distances there: the exact distance capped the same way.
    const Eigen::Vector3f cube_lo = config.map.origin_W;
    const Eigen::Vector3f cube_hi = cube_lo + Eigen::Vector3f::Constant(config.map.size_m());
    auto capped = [&](const Eigen::Vector3f& p, double exact) {
      double face = 1e9;
      for (int k = 0; k < 3; ++k) {
        if (lo[k] > cube_lo[k] + 1e-4f) face = std::min(face, static_cast<double>(p[k] - lo[k]));
        if (hi[k] < cube_hi[k] - 1e-4f) face = std::min(face, static_cast<double>(hi[k] - p[k]));
      }
      return std::min(exact, face);
    };
    std::vector<double> band_overs;
    double band_capped_sq = 0.0;
    double capped_sq = 0.0, capped_bias = 0.0, band_bias = 0.0;
    long band_near = 0;
    double band_near_sq = 0.0, band_near_field_sq = 0.0;
    long unsafe_unseen = 0;
    double close_bias = 0.0;
    long observed = 0, unsafe = 0, over_bound = 0, free_over = 0, close = 0, band = 0;
    double close_sq = 0.0, band_sq = 0.0, worst = -1e9;
    long coverage_points = 0, in_view_free = 0, in_view_distance = 0, in_view_answer = 0;
    for (long i = 0; i < o.points; ++i) {
      const Eigen::Vector3f p =
          lo + (hi - lo).cwiseProduct(Eigen::Vector3f(unit(rng), unit(rng), unit(rng)));
      const double exact = scene.distance_m(p.cast<double>());
      const PointAnswer a = query.point(p).value();
      const EsdfAnswer d = field.distance(p).value();
      const bool seen = a.state == PointState::free || a.state == PointState::near;
      if (i < 100000 && exact > voxel) {
        ++coverage_points;
        if (in_view(p.cast<double>())) {
          ++in_view_free;
          if (d.has_distance) ++in_view_distance;
          if (seen && d.has_distance) ++in_view_answer;
        }
      }
      if (!seen || exact < 0.0 || !d.has_distance) continue;
      ++observed;
      const double over = static_cast<double>(d.distance_m) - exact;
      worst = std::max(worst, over);
      if (over > voxel) {
        ++unsafe;
        const bool unseen = !nearest_surface_seen(p);
        if (unseen) ++unsafe_unseen;
        if (unsafe <= o.show_unsafe) {
          // The point, the field's answer and the surface point it implies, the exact nearest
          // surface point and what the map and the field read there.
          const Eigen::Vector3f q = nearest_surface_point(p).cast<float>();
          const PointAnswer at_q = query.point(q).value();
          const EsdfAnswer field_q = field.distance(q).value();
          const Eigen::Vector3f c = (p - lo) / field.cell_m();
          std::printf(
              "unsafe %ld: p %.3f %.3f %.3f (cell %d %d %d) %s %.3f, exact %.4f, field %.4f "
              "gradient %.2f %.2f %.2f; nearest surface %.3f %.3f %.3f%s: map %s %.4f, field "
              "%.4f\n",
              unsafe, static_cast<double>(p.x()), static_cast<double>(p.y()),
              static_cast<double>(p.z()), static_cast<int>(c.x()), static_cast<int>(c.y()),
              static_cast<int>(c.z()), point_state_name(a.state), static_cast<double>(a.distance_m),
              exact, static_cast<double>(d.distance_m), static_cast<double>(d.gradient.x()),
              static_cast<double>(d.gradient.y()), static_cast<double>(d.gradient.z()),
              static_cast<double>(q.x()), static_cast<double>(q.y()), static_cast<double>(q.z()),
              unseen ? " (unseen)" : "", point_state_name(at_q.state),
              static_cast<double>(at_q.distance_m), static_cast<double>(field_q.distance_m));
          // The map's TSDF (m, slope, scale) along the line from p through the exact surface
          // point to a few voxels inside, every half voxel: a zero crossing the field missed, or
          // none at all.
          const Eigen::Vector3f dir = (q - p).normalized();
          const float length = (q - p).norm() + 3.0f * voxel;
          std::printf("  profile:");
          for (float t = std::max(0.0f, (q - p).norm() - 6.0f * voxel); t <= length;
               t += 0.5f * voxel) {
            TsdfSample s;
            if (sample_tsdf(pipeline.map(), p + t * dir, s)) {
              std::printf(" [%.3f %.4f/%.2f s%d]", static_cast<double>(t - (q - p).norm()),
                          static_cast<double>(s.tsdf * mu),
                          static_cast<double>(s.gradient.norm() * mu), s.scale);
            } else {
              std::printf(" [%.3f -]", static_cast<double>(t - (q - p).norm()));
            }
          }
          std::printf("\n");
        }
      }
      if (static_cast<double>(d.lower_bound_m) > exact) ++over_bound;
      if (a.state == PointState::free &&
          static_cast<double>(std::max(a.distance_m, d.lower_bound_m)) > exact) {
        ++free_over;
      }
      if (exact < 1.0 && i < 200000 && nearest_surface_seen(p)) {
        ++close;
        close_sq += over * over;
        close_bias += over;
        const double over_capped = static_cast<double>(d.distance_m) - capped(p, exact);
        capped_sq += over_capped * over_capped;
        capped_bias += over_capped;
      }
      if (exact < mu && i < 200000 && nearest_surface_seen(p)) {
        ++band;
        band_overs.push_back(over);
        const double over_capped = static_cast<double>(d.distance_m) - capped(p, exact);
        band_capped_sq += over_capped * over_capped;
        band_sq += over * over;
        band_bias += over;
        if (a.state == PointState::near) {
          // The map's own distance there (the TSDF's, along rays), for comparison.
          const double tsdf_over = static_cast<double>(a.distance_m) - exact;
          ++band_near;
          band_near_sq += tsdf_over * tsdf_over;
          band_near_field_sq += over * over;
        }
      }
    }
    std::printf(
        "%ld points in the window, %ld observed (free or near) outside objects: unsafe "
        "(distance > exact + voxel) %ld (%ld of them next to a surface the map never "
        "saw), worst over %.4f m, lower bound above exact %ld, --query-points free "
        "DISTANCE above exact %ld\n",
        o.points, observed, unsafe, unsafe_unseen, worst, over_bound, free_over);
    std::printf(
        "RMSE within 1 m of a surface the map saw, in the window (of the first 200000 points) %.4f "
        "m (mean %.4f, "
        "%ld "
        "points), within mu %.4f m (%ld points)\n",
        std::sqrt(close_sq / std::max(close, 1L)), close_bias / std::max(close, 1L), close,
        std::sqrt(band_sq / std::max(band, 1L)), band);
    if (!band_overs.empty()) {
      // Where the error lies: a few answers far under (sites a thin part's dip or a box put
      // beside the surface), or all of them a little.
      std::sort(band_overs.begin(), band_overs.end());
      auto at = [&](double q) {
        return band_overs[static_cast<std::size_t>(q * static_cast<double>(band_overs.size() - 1))];
      };
      std::printf(
          "within mu: field less exact at percentiles 1 5 25 50 75 95 99: %.4f %.4f %.4f %.4f "
          "%.4f %.4f %.4f m; RMSE against the exact distance capped at the window's faces %.4f m\n",
          at(0.01), at(0.05), at(0.25), at(0.5), at(0.75), at(0.95), at(0.99),
          std::sqrt(band_capped_sq / static_cast<double>(band_overs.size())));
    }
    std::printf(
        "within mu: mean %.4f m; of those the map reads near (%ld), the field's RMSE %.4f m, the "
        "map's own near distance %.4f m\n",
        band_bias / std::max(band, 1L), band_near,
        std::sqrt(band_near_field_sq / std::max(band_near, 1L)),
        std::sqrt(band_near_sq / std::max(band_near, 1L)));
    std::printf(
        "RMSE within 1 m against the exact distance capped at the window's faces inside the cube "
        "%.4f m (mean %.4f)\n",
        std::sqrt(capped_sq / std::max(close, 1L)), capped_bias / std::max(close, 1L));
    std::printf(
        "coverage: of %ld truly free points in view (of %ld sampled), %.1f %% have a "
        "distance, %.1f %% are also read free or near\n",
        in_view_free, coverage_points, 100.0 * in_view_distance / std::max(in_view_free, 1L),
        100.0 * in_view_answer / std::max(in_view_free, 1L));
    // A batch of 10 000 queries, timed 101 times.
    std::vector<Eigen::Vector3f> batch(10000);
    for (Eigen::Vector3f& p : batch) {
      p = lo + (hi - lo).cwiseProduct(Eigen::Vector3f(unit(rng), unit(rng), unit(rng)));
    }
    std::vector<EsdfAnswer> answers(batch.size());
    std::vector<double> us;
    for (int k = 0; k < 101; ++k) {
      const auto t0 = std::chrono::steady_clock::now();
      if (!field.distances(batch.data(), batch.size(), answers.data()).ok()) return 1;
      const auto t1 = std::chrono::steady_clock::now();
      us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
    }
    std::printf("batch of 10000 distance queries: median %.0f us, p99 %.0f us\n",
                percentile(us, 0.5), percentile(us, 0.99));
    if (unsafe > unsafe_unseen) rc = 1;
  }
  return rc;
}
