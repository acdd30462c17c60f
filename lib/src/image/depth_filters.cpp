#include "octofuse/image/depth_filters.hpp"

#include <cmath>
#include <utility>

#include <Eigen/Geometry>  // cross()

namespace octofuse {

namespace {

bool same_size(int w0, int h0, int w1, int h1) {
  return w0 == w1 && h0 == h1;
}

// Runs row_fn(y) for every row of an image of `height` rows in kImageRowTasks fixed chunks.
template <typename RowFn>
void for_each_row(int height, const WorkerTeam& team, RowFn& row_fn) {
  auto task_fn = [&](std::size_t task) {
    const TaskRange r = task_range(static_cast<std::size_t>(height), task, kImageRowTasks);
    for (std::size_t y = r.begin; y < r.end; ++y) row_fn(static_cast<int>(y));
  };
  team.for_each_task(kImageRowTasks, task_fn);
}

}  // namespace

Status downsample_depth(ImageView<const float> in, ImageView<float> out, int factor, float band_m,
                        const WorkerTeam& team) {
  if (in.empty() || out.empty()) return StatusCode::invalid_argument;
  if (factor != 1 && factor != 2 && factor != 4) return StatusCode::invalid_argument;
  if (!(band_m >= 0.0f) || out.width * factor > in.width || out.height * factor > in.height) {
    return StatusCode::invalid_argument;
  }
  auto row_fn = [&](int y) {
    float* out_row = out.row(y);
    for (int x = 0; x < out.width; ++x) {
      // Valid samples of the block, sorted (at most 16).
      float samples[kMaxDownsampleFactor * kMaxDownsampleFactor];
      int n = 0;
      const float* r0 = in.row(factor * y) + factor * x;
      const float* r1 = factor == 2 ? in.row(factor * y + 1) + factor * x : nullptr;
      if (factor == 2 && valid_depth(r0[0]) && valid_depth(r0[1]) && valid_depth(r1[0]) &&
          valid_depth(r1[1])) {
        // The common case, four valid samples, through a sorting network instead of insertion:
        // the same sorted samples in a fraction of the work.
        samples[0] = r0[0];
        samples[1] = r0[1];
        samples[2] = r1[0];
        samples[3] = r1[1];
        auto order = [&samples](int i, int j) {
          if (samples[j] < samples[i]) std::swap(samples[i], samples[j]);
        };
        order(0, 1);
        order(2, 3);
        order(0, 2);
        order(1, 3);
        order(1, 2);
        n = 4;
      } else {
        for (int dy = 0; dy < factor; ++dy) {
          const float* in_row = in.row(factor * y + dy) + factor * x;
          for (int dx = 0; dx < factor; ++dx) {
            const float d = in_row[dx];
            if (!valid_depth(d)) continue;
            int i = n++;
            while (i > 0 && samples[i - 1] > d) {
              samples[i] = samples[i - 1];
              --i;
            }
            samples[i] = d;
          }
        }
      }
      if (n == 0) {
        out_row[x] = 0.0f;
        continue;
      }
      const float median = samples[(n - 1) / 2];
      float sum = 0.0f;
      int count = 0;
      for (int i = 0; i < n; ++i) {
        if (std::fabs(samples[i] - median) <= band_m) {
          sum += samples[i];
          ++count;
        }
      }
      out_row[x] = sum / static_cast<float>(count);  // count >= 1: the median itself
    }
  };
  for_each_row(out.height, team, row_fn);
  return ok_status();
}

Status bilateral_filter(ImageView<const float> in, ImageView<float> out, float sigma_space_px,
                        float sigma_range_m, const WorkerTeam& team) {
  if (in.empty() || out.empty() || !same_size(in.width, in.height, out.width, out.height)) {
    return StatusCode::invalid_argument;
  }
  if (!(sigma_space_px > 0.0f) || !(sigma_range_m > 0.0f) ||
      static_cast<const void*>(in.data) == static_cast<const void*>(out.data)) {
    return StatusCode::invalid_argument;
  }
  constexpr int kRadius = 2;
  constexpr int kSide = 2 * kRadius + 1;
  float spatial[kSide * kSide];
  const float inv_2ss = 1.0f / (2.0f * sigma_space_px * sigma_space_px);
  for (int dy = -kRadius; dy <= kRadius; ++dy) {
    for (int dx = -kRadius; dx <= kRadius; ++dx) {
      spatial[(dy + kRadius) * kSide + dx + kRadius] =
          std::exp(-static_cast<float>(dx * dx + dy * dy) * inv_2ss);
    }
  }
  const float inv_2sr = 1.0f / (2.0f * sigma_range_m * sigma_range_m);
  auto row_fn = [&](int y) {
    float* out_row = out.row(y);
    const int y0 = y - kRadius < 0 ? 0 : y - kRadius;
    const int y1 = y + kRadius >= in.height ? in.height - 1 : y + kRadius;
    for (int x = 0; x < in.width; ++x) {
      const float centre = in(x, y);
      if (!valid_depth(centre)) {
        out_row[x] = 0.0f;
        continue;
      }
      const int x0 = x - kRadius < 0 ? 0 : x - kRadius;
      const int x1 = x + kRadius >= in.width ? in.width - 1 : x + kRadius;
      float sum = 0.0f;
      float weight_sum = 0.0f;
      for (int yy = y0; yy <= y1; ++yy) {
        const float* in_row = in.row(yy);
        const float* w_row = spatial + (yy - y + kRadius) * kSide + kRadius - x;
        for (int xx = x0; xx <= x1; ++xx) {
          const float d = in_row[xx];
          if (!valid_depth(d)) continue;
          const float diff = d - centre;
          const float w = w_row[xx] * std::exp(-diff * diff * inv_2sr);
          sum += w * d;
          weight_sum += w;
        }
      }
      out_row[x] = sum / weight_sum;  // weight_sum >= 1: the centre's own weight
    }
  };
  for_each_row(in.height, team, row_fn);
  return ok_status();
}

Status depth_to_vertices(ImageView<const float> depth_m, const PinholeCamera& camera,
                         ImageView<Eigen::Vector3f> vertices_C, const WorkerTeam& team) {
  if (depth_m.empty() || vertices_C.empty() || !camera.valid() ||
      !same_size(depth_m.width, depth_m.height, vertices_C.width, vertices_C.height) ||
      !same_size(depth_m.width, depth_m.height, camera.width, camera.height)) {
    return StatusCode::invalid_argument;
  }
  auto row_fn = [&](int y) {
    const float* d_row = depth_m.row(y);
    Eigen::Vector3f* v_row = vertices_C.row(y);
    const float fy_y = static_cast<float>(y);
    for (int x = 0; x < depth_m.width; ++x) {
      const float d = d_row[x];
      v_row[x] = valid_depth(d) ? camera.back_project(static_cast<float>(x), fy_y, d)
                                : Eigen::Vector3f::Zero();
    }
  };
  for_each_row(depth_m.height, team, row_fn);
  return ok_status();
}

Status vertices_to_normals(ImageView<const float> depth_m,
                           ImageView<const Eigen::Vector3f> vertices_C, float max_depth_jump_m,
                           ImageView<Eigen::Vector3f> normals_C, const WorkerTeam& team) {
  if (depth_m.empty() || vertices_C.empty() || normals_C.empty() ||
      !same_size(depth_m.width, depth_m.height, vertices_C.width, vertices_C.height) ||
      !same_size(depth_m.width, depth_m.height, normals_C.width, normals_C.height) ||
      !(max_depth_jump_m >= 0.0f)) {
    return StatusCode::invalid_argument;
  }
  const int w = depth_m.width;
  const int h = depth_m.height;
  auto row_fn = [&](int y) {
    Eigen::Vector3f* n_row = normals_C.row(y);
    for (int x = 0; x < w; ++x) {
      n_row[x] = Eigen::Vector3f::Zero();
      if (x == 0 || y == 0 || x == w - 1 || y == h - 1) continue;
      const float d = depth_m(x, y);
      const float d_left = depth_m(x - 1, y);
      const float d_right = depth_m(x + 1, y);
      const float d_up = depth_m(x, y - 1);
      const float d_down = depth_m(x, y + 1);
      if (!valid_depth(d) || !valid_depth(d_left) || !valid_depth(d_right) || !valid_depth(d_up) ||
          !valid_depth(d_down)) {
        continue;
      }
      if (std::fabs(d_left - d) > max_depth_jump_m || std::fabs(d_right - d) > max_depth_jump_m ||
          std::fabs(d_up - d) > max_depth_jump_m || std::fabs(d_down - d) > max_depth_jump_m) {
        continue;
      }
      const Eigen::Vector3f dx = vertices_C(x + 1, y) - vertices_C(x - 1, y);
      const Eigen::Vector3f dy = vertices_C(x, y + 1) - vertices_C(x, y - 1);
      const Eigen::Vector3f n = dy.cross(dx);
      const float norm = n.norm();
      if (norm > 0.0f && std::isfinite(norm)) n_row[x] = n / norm;
    }
  };
  for_each_row(h, team, row_fn);
  return ok_status();
}

}  // namespace octofuse
