#include "octofuse/query/free_space.hpp"

#include <algorithm>
#include <cmath>

namespace octofuse {

Status validate(const FreeSpaceConfig& config) {
  const bool finite = std::isfinite(config.margin_m) && std::isfinite(config.clearance_m) &&
                      std::isfinite(config.occlusion_clear_m) && std::isfinite(config.near_m);
  if (!finite || config.margin_m < 0.0f || config.clearance_m < 0.0f ||
      config.occlusion_clear_m < 0.0f || config.near_m < 0.0f) {
    return StatusCode::invalid_argument;
  }
  if (config.finest_octant_voxels != 2 && config.finest_octant_voxels != 4 &&
      config.finest_octant_voxels != 8) {
    return StatusCode::invalid_argument;
  }
  if (config.max_free_count == 0 || config.max_node_visits == 0) {
    return StatusCode::invalid_argument;
  }
  return ok_status();
}

void FreeSpace::clear() {
  OCTOFUSE_CHECK(reserved_);
  nodes_.reset();
  const Result<std::uint32_t> root = nodes_.allocate();
  OCTOFUSE_CHECK(root.ok() && root.value() == 0);
}

Status FreeSpace::begin_restore(std::uint32_t count) {
  if (!reserved_) return StatusCode::failed_precondition;
  clear();
  if (count == 0 || count > nodes_.capacity()) return StatusCode::resource_exhausted;
  for (std::uint32_t i = 1; i < count; ++i) {
    const Result<std::uint32_t> fresh = nodes_.allocate();
    OCTOFUSE_CHECK(fresh.ok() && fresh.value() == i);
  }
  return ok_status();
}

void FreeSpace::build_pyramid(ImageView<const float> depth_m) {
  float* lo = depth_min_;
  float* hi = depth_max_;
  for (int y = 0; y < height_; ++y) {
    const float* row = depth_m.row(y);
    for (int x = 0; x < width_; ++x) {
      const float d = row[x];
      // NaN and infinities fail the test: invalid pixels are 0 in both images.
      const float v = (d > 0.0f && d < 1e30f) ? d : 0.0f;
      lo[y * width_ + x] = v;
      hi[y * width_ + x] = v;
    }
  }
  for (int level = 1; level < level_count_; ++level) {
    const int w = level_width_[level];
    const int h = level_height_[level];
    const int pw = level_width_[level - 1];
    const int ph = level_height_[level - 1];
    const float* plo = depth_min_ + level_offset_[level - 1];
    const float* phi = depth_max_ + level_offset_[level - 1];
    float* clo = depth_min_ + level_offset_[level];
    float* chi = depth_max_ + level_offset_[level];
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        float a = 1e30f;
        float b = 0.0f;
        for (int dy = 0; dy < 2; ++dy) {
          const int py = 2 * y + dy;
          if (py >= ph) break;
          for (int dx = 0; dx < 2; ++dx) {
            const int px = 2 * x + dx;
            if (px >= pw) break;
            a = std::min(a, plo[py * pw + px]);
            b = std::max(b, phi[py * pw + px]);
          }
        }
        clo[y * w + x] = a;
        chi[y * w + x] = b;
      }
    }
  }
}

void FreeSpace::tile_range(int level, int u0, int v0, int u1, int v1, float& lo, float& hi) const {
  const int w = level_width_[level];
  const float* plo = depth_min_ + level_offset_[level];
  const float* phi = depth_max_ + level_offset_[level];
  lo = 1e30f;
  hi = 0.0f;
  for (int y = v0 >> level; y <= (v1 >> level); ++y) {
    for (int x = u0 >> level; x <= (u1 >> level); ++x) {
      lo = std::min(lo, plo[y * w + x]);
      hi = std::max(hi, phi[y * w + x]);
    }
  }
}

namespace {
int clamped_floor(float f) {
  constexpr float kLimit = 1e6f;
  if (!(f > -kLimit)) return -1000000;
  if (!(f < kLimit)) return 1000000;
  return static_cast<int>(std::floor(f));
}
}  // namespace

FreeSpace::Seen FreeSpace::classify(const Eigen::Vector3i& min_voxel, int size_voxels) const {
  const float voxel = map_.voxel_size_m;
  const Eigen::Vector3f lo_W =
      map_.origin_W + min_voxel.cast<float>() * voxel - Eigen::Vector3f::Constant(margin_m_);
  const float side = static_cast<float>(size_voxels) * voxel + 2.0f * margin_m_;
  float z_min = 1e30f;
  float z_max = -1e30f;
  // One transform, then the cube's edges in the camera frame (the columns of R_C_W scaled).
  Eigen::Vector3f corners_C[8];
  const Eigen::Vector3f base_C = R_C_W_ * lo_W + t_C_W_;
  const Eigen::Vector3f ex = R_C_W_.col(0) * side;
  const Eigen::Vector3f ey = R_C_W_.col(1) * side;
  const Eigen::Vector3f ez = R_C_W_.col(2) * side;
  for (int c = 0; c < 8; ++c) {
    Eigen::Vector3f p = base_C;
    if (c & 1) p += ex;
    if (c & 2) p += ey;
    if (c & 4) p += ez;
    corners_C[c] = p;
    z_min = std::min(z_min, p.z());
    z_max = std::max(z_max, p.z());
  }
  if (z_max <= config_.near_m) return Seen::not_seen;  // behind the camera
  // Wholly outside one side plane of the view frustum (planes through the camera centre, so
  // this holds for octants straddling the camera plane too).
  const float left = camera_.cx + 0.5f;
  const float right = camera_.cx - (static_cast<float>(width_) - 0.5f);
  const float top = camera_.cy + 0.5f;
  const float bottom = camera_.cy - (static_cast<float>(height_) - 0.5f);
  int out_left = 0;
  int out_right = 0;
  int out_top = 0;
  int out_bottom = 0;
  for (int c = 0; c < 8; ++c) {
    const Eigen::Vector3f& p = corners_C[c];
    out_left += camera_.fx * p.x() + left * p.z() < 0.0f ? 1 : 0;
    out_right += camera_.fx * p.x() + right * p.z() >= 0.0f ? 1 : 0;
    out_top += camera_.fy * p.y() + top * p.z() < 0.0f ? 1 : 0;
    out_bottom += camera_.fy * p.y() + bottom * p.z() >= 0.0f ? 1 : 0;
  }
  if (out_left == 8 || out_right == 8 || out_top == 8 || out_bottom == 8) return Seen::not_seen;
  // Straddles the camera plane: its projection is unbounded.
  if (z_min <= config_.near_m) return Seen::partial;
  float u_min = 1e30f;
  float u_max = -1e30f;
  float v_min = 1e30f;
  float v_max = -1e30f;
  for (int c = 0; c < 8; ++c) {
    const Eigen::Vector2f px = camera_.project(corners_C[c]);
    u_min = std::min(u_min, px.x());
    u_max = std::max(u_max, px.x());
    v_min = std::min(v_min, px.y());
    v_max = std::max(v_max, px.y());
  }
  // The projection of a convex body in front of the camera lies in the hull of its corners'.
  const float w = static_cast<float>(width_);
  const float h = static_cast<float>(height_);
  if (u_max < -0.5f || v_max < -0.5f || u_min >= w - 0.5f || v_min >= h - 0.5f) {
    return Seen::not_seen;
  }
  // Pixel u covers [u - 0.5, u + 0.5); one more pixel on each side for the depth step between
  // neighbouring pixels.
  int u0 = clamped_floor(u_min + 0.5f) - 1;
  int u1 = clamped_floor(u_max + 0.5f) + 1;
  int v0 = clamped_floor(v_min + 0.5f) - 1;
  int v1 = clamped_floor(v_max + 0.5f) + 1;
  const bool inside = u0 >= 0 && v0 >= 0 && u1 < width_ && v1 < height_;
  u0 = std::max(u0, 0);
  v0 = std::max(v0, 0);
  u1 = std::min(u1, width_ - 1);
  v1 = std::min(v1, height_ - 1);
  // The finest level where the range spans at most 2 x 2 tiles.
  int level = 0;
  while (level + 1 < level_count_ &&
         (((u1 >> level) - (u0 >> level)) > 1 || ((v1 >> level) - (v0 >> level)) > 1)) {
    ++level;
  }
  float depth_lo = 0.0f;
  float depth_hi = 0.0f;
  tile_range(level, u0, v0, u1, v1, depth_lo, depth_hi);
  if (inside && depth_lo > 0.0f && z_max < depth_lo - clearance_m_) return Seen::free;
  if (depth_hi <= 0.0f || z_min > depth_hi + occlusion_clear_m_) return Seen::not_seen;
  if (z_min > depth_hi) return Seen::occluded;
  return Seen::partial;
}

FreeSpaceReport FreeSpace::carve(ImageView<const float> depth_m, const PinholeCamera& camera,
                                 const Se3d& T_W_C, std::uint32_t frame) {
  FreeSpaceReport report;
  if (!reserved_ || depth_m.width != width_ || depth_m.height != height_) return report;
  build_pyramid(depth_m);
  const Se3f T_C_W = T_W_C.inverse().cast<float>();
  R_C_W_ = T_C_W.linear();
  t_C_W_ = T_C_W.translation();
  camera_ = camera;

  struct Entry {
    std::uint32_t node;
    std::uint32_t parent;
    std::uint8_t slot;
    std::uint8_t level;
    Eigen::Vector3i min_voxel;
  };
  Entry stack[kStackCapacity];
  int top = 0;
  stack[top++] = Entry{0, kNoNode, 0, 0, Eigen::Vector3i::Zero()};
  const int depth = map_.voxel_depth;
  const int leaf = leaf_level();

  auto allocate_child = [&](std::uint32_t parent, int slot) -> std::uint32_t {
    if (report.new_nodes >= config_.max_new_nodes) {
      ++report.refused;
      report.budget_hit = true;
      return kNoNode;
    }
    const Result<std::uint32_t> fresh = nodes_.allocate();
    if (!fresh.ok()) {
      ++report.refused;
      return kNoNode;
    }
    ++report.new_nodes;
    nodes_[parent].children[slot] = fresh.value();
    return fresh.value();
  };

  while (top > 0) {
    const Entry e = stack[--top];
    if (report.node_visits >= config_.max_node_visits) {
      report.budget_hit = true;
      break;
    }
    ++report.node_visits;
    const int size = 1 << (depth - e.level);
    const Seen seen = classify(e.min_voxel, size);
    if (seen == Seen::not_seen) continue;
    std::uint32_t index = e.node;
    if (seen == Seen::free) {
      if (index == kNoNode) index = allocate_child(e.parent, e.slot);
      if (index == kNoNode) continue;
      FreeNode& n = nodes_[index];
      n.free_count = static_cast<std::uint8_t>(
          std::min<int>(n.free_count + 1, static_cast<int>(config_.max_free_count)));
      n.free_frame = frame;
      ++report.marked_free;
      continue;
    }
    // Partly seen: what this frame shows inside decides each part.
    if (e.level == leaf) {
      if (index != kNoNode && nodes_[index].free_count > 0) {
        nodes_[index].free_count = 0;
        ++report.cleared;
      }
      continue;
    }
    // Occluded: nothing recorded below means nothing to clear.
    if (index == kNoNode && seen == Seen::occluded) continue;
    if (index == kNoNode) index = allocate_child(e.parent, e.slot);
    if (index == kNoNode) continue;
    if (nodes_[index].free_count > 0) {
      const std::uint8_t count = nodes_[index].free_count;
      const std::uint32_t when = nodes_[index].free_frame;
      for (int c = 0; c < 8; ++c) {
        std::uint32_t child = nodes_[index].children[c];
        if (child == kNoNode) child = allocate_child(index, c);
        // Refused: that part loses its free state (never wrongly free).
        if (child == kNoNode) continue;
        FreeNode& k = nodes_[child];
        if (k.free_count == 0 || k.free_frame < when) {
          k.free_count = count;
          k.free_frame = when;
        }
      }
      nodes_[index].free_count = 0;
      ++report.cleared;
    }
    const int half = size / 2;
    for (int c = 7; c >= 0; --c) {
      if (seen == Seen::occluded && nodes_[index].children[c] == kNoNode) continue;
      const Eigen::Vector3i offset((c & 1) ? half : 0, (c & 2) ? half : 0, (c & 4) ? half : 0);
      stack[top++] = Entry{nodes_[index].children[c], index, static_cast<std::uint8_t>(c),
                           static_cast<std::uint8_t>(e.level + 1), e.min_voxel + offset};
    }
  }
  report.nodes_used = nodes_.used();
  report.bytes_used = bytes_used();
  return report;
}

FreeOctant FreeSpace::find(const Eigen::Vector3i& voxel) const {
  FreeOctant out;
  if (!reserved_) return out;
  const int depth = map_.voxel_depth;
  const int n = 1 << depth;
  if (voxel.x() < 0 || voxel.y() < 0 || voxel.z() < 0 || voxel.x() >= n || voxel.y() >= n ||
      voxel.z() >= n) {
    return out;
  }
  const int leaf = leaf_level();
  std::uint32_t index = 0;
  for (int level = 0;; ++level) {
    const FreeNode& node = nodes_[index];
    if (node.free_count > 0) {
      const int size = 1 << (depth - level);
      out.free = true;
      out.free_frame = node.free_frame;
      out.level = level;
      out.size_voxels = size;
      out.min_voxel = Eigen::Vector3i(voxel.x() & ~(size - 1), voxel.y() & ~(size - 1),
                                      voxel.z() & ~(size - 1));
      return out;
    }
    if (level == leaf) return out;
    const int bit = depth - level - 1;
    const int child = ((voxel.x() >> bit) & 1) | (((voxel.y() >> bit) & 1) << 1) |
                      (((voxel.z() >> bit) & 1) << 2);
    index = node.children[child];
    if (index == kNoNode) return out;
  }
}

}  // namespace octofuse
