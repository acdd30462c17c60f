#include "octofuse/ports/sim/renderer.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "dot3.hpp"
#include "octofuse/ports/sim/random.hpp"

namespace octofuse::sim {
namespace {

// Corners closer to the camera plane than this make the projection unbounded: such a primitive
// is listed in every tile.
constexpr double kNearPlane_m = 1e-3;

}  // namespace

void SceneRenderer::bin_primitives(const Scene& scene, const Se3d& T_W_C, int margin_px) {
  const int tiles = tiles_x_ * tiles_y_;
  std::fill(tile_counts_, tile_counts_ + tiles, std::uint16_t{0});
  const Eigen::Matrix3d R_W_C = T_W_C.linear();
  const Eigen::Matrix3d R_C_W = R_W_C.transpose();
  const Eigen::Vector3d t_W_C = T_W_C.translation();
  stats_.visible_primitives = 0;

  for (std::size_t i = 0; i < scene.size(); ++i) {
    const Primitive& p = scene[i];
    FramePrimitive& fp = frame_primitives_[i];
    fp.R_P_C = p.R_W_P.transpose() * R_W_C;
    fp.o_P = p.R_W_P.transpose() * (t_W_C - p.t_W_P);
    fp.primitive = &p;

    int tx0 = 0;
    int ty0 = 0;
    int tx1 = tiles_x_ - 1;
    int ty1 = tiles_y_ - 1;
    if (!p.bounded()) {
      if (fp.o_P.z() <= 0.0) continue;  // camera inside the half-space: never seen
    } else {
      double u_min = std::numeric_limits<double>::infinity();
      double v_min = u_min;
      double u_max = -u_min;
      double v_max = -u_min;
      int behind = 0;
      bool straddles = false;
      for (int c = 0; c < 8; ++c) {
        const Eigen::Vector3d corner_W((c & 1) ? p.aabb_max_W.x() : p.aabb_min_W.x(),
                                       (c & 2) ? p.aabb_max_W.y() : p.aabb_min_W.y(),
                                       (c & 4) ? p.aabb_max_W.z() : p.aabb_min_W.z());
        const Eigen::Vector3d c_C = R_C_W * (corner_W - t_W_C);
        if (c_C.z() < kNearPlane_m) {
          ++behind;
          straddles = true;
          continue;
        }
        const double u = camera_.fx * c_C.x() / c_C.z() + camera_.cx;
        const double v = camera_.fy * c_C.y() / c_C.z() + camera_.cy;
        u_min = std::min(u_min, u);
        u_max = std::max(u_max, u);
        v_min = std::min(v_min, v);
        v_max = std::max(v_max, v);
      }
      if (behind == 8) continue;
      if (!straddles) {
        // Pixel centres sit at integers; a ray may stray margin_px from its centre.
        const double m = margin_px;
        const double w = camera_.width - 1;
        const double h = camera_.height - 1;
        if (u_max + m < 0.0 || v_max + m < 0.0 || u_min - m > w || v_min - m > h) continue;
        tx0 = static_cast<int>(std::max(0.0, std::floor(u_min - m))) / kTileSize;
        ty0 = static_cast<int>(std::max(0.0, std::floor(v_min - m))) / kTileSize;
        tx1 = static_cast<int>(std::min(w, std::ceil(u_max + m))) / kTileSize;
        ty1 = static_cast<int>(std::min(h, std::ceil(v_max + m))) / kTileSize;
      }
    }
    ++stats_.visible_primitives;
    for (int ty = ty0; ty <= ty1; ++ty) {
      for (int tx = tx0; tx <= tx1; ++tx) {
        const int tile = ty * tiles_x_ + tx;
        tile_lists_[static_cast<std::size_t>(tile) * Scene::kMaxPrimitives + tile_counts_[tile]++] =
            static_cast<std::uint16_t>(i);
      }
    }
  }
}

Status SceneRenderer::render(const Scene& scene, const Se3d& T_W_C, const RenderOptions& options,
                             ImageView<float> depth_m, ImageView<float> cos_incidence) {
  if (!ready_) return StatusCode::failed_precondition;
  const bool want_cos = !cos_incidence.empty();
  if (depth_m.data == nullptr || depth_m.width != camera_.width ||
      depth_m.height != camera_.height ||
      (want_cos &&
       (cos_incidence.width != camera_.width || cos_incidence.height != camera_.height))) {
    return StatusCode::invalid_argument;
  }
  if (!is_rigid(T_W_C.matrix())) return StatusCode::invalid_argument;
  if (!std::isfinite(options.max_range_m) || !(options.max_range_m > 0.0f) ||
      !std::isfinite(options.lateral_sigma_px) || options.lateral_sigma_px < 0.0f) {
    return StatusCode::invalid_argument;
  }

  stats_ = RenderStats();
  // Irwin-Hall jitter is bounded by sqrt(12) sigma.
  const double sigma_px = options.lateral_sigma_px;
  const int margin_px = 1 + static_cast<int>(std::ceil(3.4642 * sigma_px));
  bin_primitives(scene, T_W_C, margin_px);

  const double inv_fx = 1.0 / camera_.fx;
  const double inv_fy = 1.0 / camera_.fy;
  const double cx = camera_.cx;
  const double cy = camera_.cy;
  const double max_range = options.max_range_m;
  std::uint64_t tests = 0;
  std::uint32_t hits = 0;

  for (int ty = 0; ty < tiles_y_; ++ty) {
    for (int tx = 0; tx < tiles_x_; ++tx) {
      const int tile = ty * tiles_x_ + tx;
      const std::uint16_t* list =
          tile_lists_ + static_cast<std::size_t>(tile) * Scene::kMaxPrimitives;
      const int count = tile_counts_[tile];
      const int x_end = std::min(camera_.width, (tx + 1) * kTileSize);
      const int y_end = std::min(camera_.height, (ty + 1) * kTileSize);
      for (int y = ty * kTileSize; y < y_end; ++y) {
        float* depth_row = depth_m.row(y);
        float* cos_row = want_cos ? cos_incidence.row(y) : nullptr;
        for (int x = tx * kTileSize; x < x_end; ++x) {
          double u = x;
          double v = y;
          if (sigma_px > 0.0) {
            const std::uint64_t pixel = static_cast<std::uint64_t>(y) * camera_.width + x;
            u += sigma_px * gaussian_from_bits(hash_key(options.jitter_key, pixel, 0, 1));
            v += sigma_px * gaussian_from_bits(hash_key(options.jitter_key, pixel, 0, 2));
          }
          // The unit ray and its rotation into each primitive's frame in scalars (dot3.hpp).
          const double x_C = (u - cx) * inv_fx;
          const double y_C = (v - cy) * inv_fy;
          const double inv_norm = 1.0 / std::sqrt(dot3(x_C, y_C, 1.0, x_C, y_C, 1.0));
          const double dx_C = x_C * inv_norm;
          const double dy_C = y_C * inv_norm;
          const double dz_C = inv_norm;  // the depth per metre of ray
          const double t_limit = max_range / dz_C;
          double best_t = t_limit;
          double best_cos = 0.0;
          bool hit = false;
          for (int k = 0; k < count; ++k) {
            const FramePrimitive& fp = frame_primitives_[list[k]];
            const Eigen::Matrix3d& R = fp.R_P_C;
            const Eigen::Vector3d d_P(dot3(R(0, 0), R(0, 1), R(0, 2), dx_C, dy_C, dz_C),
                                      dot3(R(1, 0), R(1, 1), R(1, 2), dx_C, dy_C, dz_C),
                                      dot3(R(2, 0), R(2, 1), R(2, 2), dx_C, dy_C, dz_C));
            double t;
            double c;
            if (fp.primitive->intersect_local(fp.o_P, d_P, &t, &c) && t < best_t) {
              best_t = t;
              best_cos = c;
              hit = true;
            }
          }
          tests += static_cast<std::uint64_t>(count);
          if (hit) ++hits;
          depth_row[x] = hit ? static_cast<float>(best_t * dz_C) : 0.0f;
          if (want_cos) cos_row[x] = hit ? static_cast<float>(best_cos) : 0.0f;
        }
      }
    }
  }
  stats_.primitive_tests = tests;
  stats_.hit_pixels = hits;
  return ok_status();
}

}  // namespace octofuse::sim
