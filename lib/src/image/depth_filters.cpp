#include "octofuse/image/depth_filters.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Geometry>  // cross()

namespace octofuse {

namespace {

// Pixels per chunk of a row in the branch-free loops (their scratch arrays live on the stack).
constexpr int kRowChunk = 64;

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
  // One output pixel from the valid samples of its block: the mean of those within band_m of
  // their median.
  auto block_fn = [&](int x, int y) {
    // Valid samples of the block, sorted (at most 16).
    float samples[kMaxDownsampleFactor * kMaxDownsampleFactor];
    int n = 0;
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
    if (n == 0) return 0.0f;
    const float median = samples[(n - 1) / 2];
    float sum = 0.0f;
    int count = 0;
    for (int i = 0; i < n; ++i) {
      if (std::fabs(samples[i] - median) <= band_m) {
        sum += samples[i];
        ++count;
      }
    }
    return sum / static_cast<float>(count);  // count >= 1: the median itself
  };
  auto row_fn = [&](int y) {
    float* out_row = out.row(y);
    if (factor != 2) {
      for (int x = 0; x < out.width; ++x) out_row[x] = block_fn(x, y);
      return;
    }
    // The common case, a 2 x 2 block of four valid samples, in a loop without branches
    // (vectorised where the target's SIMD rounds as scalar code does): a sorting network of
    // min/max, the median the second sample, the band's samples summed in sorted order, as
    // block_fn() does them. Blocks with an invalid sample are done again by block_fn().
    const float* r0 = in.row(2 * y);
    const float* r1 = in.row(2 * y + 1);
    for (int x0 = 0; x0 < out.width; x0 += kRowChunk) {
      const int count = std::min(kRowChunk, out.width - x0);
      unsigned char all_valid[kRowChunk];
      for (int k = 0; k < count; ++k) {
        const int x = x0 + k;
        float s0 = r0[2 * x];
        float s1 = r0[2 * x + 1];
        float s2 = r1[2 * x];
        float s3 = r1[2 * x + 1];
        // Locals, then bitwise: no branch in the loop.
        const bool valid0 = valid_depth(s0);
        const bool valid1 = valid_depth(s1);
        const bool valid2 = valid_depth(s2);
        const bool valid3 = valid_depth(s3);
        all_valid[k] = static_cast<unsigned char>(valid0 & valid1 & valid2 & valid3);
        auto order = [](float& a, float& b) {
          const float lo = b < a ? b : a;
          const float hi = b < a ? a : b;
          a = lo;
          b = hi;
        };
        order(s0, s1);
        order(s2, s3);
        order(s0, s2);
        order(s1, s3);
        order(s1, s2);
        const float median = s1;
        float sum = 0.0f;
        float n = 0.0f;
        const bool in0 = std::fabs(s0 - median) <= band_m;
        const bool in1 = std::fabs(s1 - median) <= band_m;
        const bool in2 = std::fabs(s2 - median) <= band_m;
        const bool in3 = std::fabs(s3 - median) <= band_m;
        sum = in0 ? sum + s0 : sum;
        n = in0 ? n + 1.0f : n;
        sum = in1 ? sum + s1 : sum;
        n = in1 ? n + 1.0f : n;
        sum = in2 ? sum + s2 : sum;
        n = in2 ? n + 1.0f : n;
        sum = in3 ? sum + s3 : sum;
        n = in3 ? n + 1.0f : n;
        out_row[x] = sum / n;  // n >= 1 for valid samples: the median itself
      }
      for (int k = 0; k < count; ++k) {
        if (all_valid[k] == 0) out_row[x0 + k] = block_fn(x0 + k, y);
      }
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
  // Chunks of a row in three passes: the vertex differences copied out of the interleaved
  // vertices, the tests and the normal in a loop without branches (vectorised where the target's
  // SIMD rounds as the scalar code does), and the normals stored back. Each pixel's operations
  // and their order are those of the plain per-pixel code, so the bits are too.
  auto row_fn = [&](int y) {
    Eigen::Vector3f* n_row = normals_C.row(y);
    if (y == 0 || y == h - 1 || w < 3) {
      for (int x = 0; x < w; ++x) n_row[x] = Eigen::Vector3f::Zero();
      return;
    }
    n_row[0] = Eigen::Vector3f::Zero();
    n_row[w - 1] = Eigen::Vector3f::Zero();
    const float* d_up = depth_m.row(y - 1);
    const float* d_mid = depth_m.row(y);
    const float* d_down = depth_m.row(y + 1);
    const Eigen::Vector3f* v_up = vertices_C.row(y - 1);
    const Eigen::Vector3f* v_mid = vertices_C.row(y);
    const Eigen::Vector3f* v_down = vertices_C.row(y + 1);
    for (int x0 = 1; x0 < w - 1; x0 += kRowChunk) {
      const int count = std::min(kRowChunk, w - 1 - x0);
      // The differences over the interleaved floats (one contiguous loop: a row of Vector3f is
      // 3 w floats), then split into one array per component.
      static_assert(sizeof(Eigen::Vector3f) == 3 * sizeof(float), "Vector3f is three floats");
      float dx_xyz[3 * kRowChunk];
      float dy_xyz[3 * kRowChunk];
      const float* const right = v_mid[x0 + 1].data();
      const float* const left = v_mid[x0 - 1].data();
      const float* const below = v_down[x0].data();
      const float* const above = v_up[x0].data();
      for (int j = 0; j < 3 * count; ++j) {
        dx_xyz[j] = right[j] - left[j];
        dy_xyz[j] = below[j] - above[j];
      }
      float dx[3][kRowChunk];
      float dy[3][kRowChunk];
      for (int k = 0; k < count; ++k) {
        for (int c = 0; c < 3; ++c) {
          dx[c][k] = dx_xyz[3 * k + c];
          dy[c][k] = dy_xyz[3 * k + c];
        }
      }
      float n[3][kRowChunk];
      for (int k = 0; k < count; ++k) {
        const int x = x0 + k;
        const float d = d_mid[x];
        const float d_left = d_mid[x - 1];
        const float d_right = d_mid[x + 1];
        const float d_above = d_up[x];
        const float d_below = d_down[x];
        // Each test in a local, then combined bitwise: no branch in the loop.
        const bool valid_centre = valid_depth(d);
        const bool valid_left = valid_depth(d_left);
        const bool valid_right = valid_depth(d_right);
        const bool valid_above = valid_depth(d_above);
        const bool valid_below = valid_depth(d_below);
        const bool smooth_left = std::fabs(d_left - d) <= max_depth_jump_m;
        const bool smooth_right = std::fabs(d_right - d) <= max_depth_jump_m;
        const bool smooth_above = std::fabs(d_above - d) <= max_depth_jump_m;
        const bool smooth_below = std::fabs(d_below - d) <= max_depth_jump_m;
        const bool valid = valid_centre & valid_left & valid_right & valid_above & valid_below;
        const bool smooth = smooth_left & smooth_right & smooth_above & smooth_below;
        // dy x dx, as Eigen's cross() computes it; the norm as its squaredNorm() sums (a
        // binary tree: x^2 + (y^2 + z^2)).
        const float nx = dy[1][k] * dx[2][k] - dy[2][k] * dx[1][k];
        const float ny = dy[2][k] * dx[0][k] - dy[0][k] * dx[2][k];
        const float nz = dy[0][k] * dx[1][k] - dy[1][k] * dx[0][k];
        const float norm = std::sqrt(nx * nx + (ny * ny + nz * nz));
        // Finite: no more than the largest float (false for NaN too).
        const bool ok =
            valid & smooth & (norm > 0.0f) & (norm <= std::numeric_limits<float>::max());
        const float divisor = ok ? norm : 1.0f;
        n[0][k] = ok ? nx / divisor : 0.0f;
        n[1][k] = ok ? ny / divisor : 0.0f;
        n[2][k] = ok ? nz / divisor : 0.0f;
      }
      for (int k = 0; k < count; ++k) n_row[x0 + k] = Eigen::Vector3f(n[0][k], n[1][k], n[2][k]);
    }
  };
  for_each_row(h, team, row_fn);
  return ok_status();
}

}  // namespace octofuse
