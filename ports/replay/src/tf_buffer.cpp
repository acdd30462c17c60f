#include "octofuse/ports/replay/tf_buffer.hpp"

#include <cstring>

namespace octofuse::replay {
namespace {

// As pose_to_se3 does it, so that a transform taken at its own stamp is bit for bit the one
// the message gave.
Se3d to_se3(const TfSample& s) {
  const Eigen::Quaterniond q(s.q[3], s.q[0], s.q[1], s.q[2]);
  Se3d T;
  T.setIdentity();
  T.linear() = q.normalized().toRotationMatrix();
  T.translation() = Eigen::Vector3d(s.t[0], s.t[1], s.t[2]);
  return T;
}

Se3d blend(const TfSample& a, const TfSample& b, std::int64_t stamp_ns) {
  // a <= t < b; unsigned differences, which cannot overflow for any stamps a bag may hold.
  const auto since = [](std::int64_t later, std::int64_t earlier) {
    return static_cast<double>(static_cast<std::uint64_t>(later) -
                               static_cast<std::uint64_t>(earlier));
  };
  const double w = since(stamp_ns, a.stamp_ns) / since(b.stamp_ns, a.stamp_ns);
  const Eigen::Quaterniond qa = Eigen::Quaterniond(a.q[3], a.q[0], a.q[1], a.q[2]).normalized();
  const Eigen::Quaterniond qb = Eigen::Quaterniond(b.q[3], b.q[0], b.q[1], b.q[2]).normalized();
  Se3d T;
  T.setIdentity();
  T.linear() = qa.slerp(w, qb).normalized().toRotationMatrix();
  T.translation() = (1.0 - w) * Eigen::Vector3d(a.t[0], a.t[1], a.t[2]) +
                    w * Eigen::Vector3d(b.t[0], b.t[1], b.t[2]);
  return T;
}

}  // namespace

void TfHistory::attach(TfSample* samples, int capacity) {
  samples_ = samples;
  capacity_ = capacity;
  clear();
}

void TfHistory::clear() {
  first_ = count_ = 0;
  static_ = dropped_ = false;
}

void TfHistory::push(const TfSample& s, bool is_static) {
  if (is_static || static_) {
    // A static edge has one transform; a moving one republished as static (or the reverse)
    // starts again.
    first_ = 0;
    count_ = 1;
    dropped_ = false;
    static_ = is_static;
    samples_[0] = s;
    return;
  }
  if (count_ == 0 || s.stamp_ns > sample(count_ - 1).stamp_ns) {
    if (count_ == capacity_) {
      first_ = (first_ + 1) % capacity_;
      --count_;
      dropped_ = true;
    }
    sample(count_++) = s;
    return;
  }
  // Out of stamp order (rare): insert in place.
  int i = count_;
  while (i > 0 && sample(i - 1).stamp_ns > s.stamp_ns) --i;
  if (i > 0 && sample(i - 1).stamp_ns == s.stamp_ns) {
    sample(i - 1) = s;
    return;
  }
  if (count_ == capacity_) {
    if (i == 0) {
      dropped_ = true;  // older than all the ring holds
      return;
    }
    first_ = (first_ + 1) % capacity_;
    --count_;
    --i;
    dropped_ = true;
  }
  for (int j = count_; j > i; --j) sample(j) = sample(j - 1);
  sample(i) = s;
  ++count_;
}

TfAt TfHistory::at(std::int64_t stamp_ns, bool final, Se3d* T, unsigned* stale) const {
  if (count_ == 0) return TfAt::none;
  const TfSample& newest = sample(count_ - 1);
  if (static_) {
    *T = to_se3(newest);
    return TfAt::ready;
  }
  if (newest.stamp_ns < stamp_ns) {
    if (!final) return TfAt::wait;
    *T = to_se3(newest);
    *stale |= kTfPastEnd;
    return TfAt::ready;
  }
  // The first transform at or after the time (binary search over the sorted ring).
  int lo = 0, hi = count_ - 1;
  while (lo < hi) {
    const int mid = (lo + hi) / 2;
    if (sample(mid).stamp_ns < stamp_ns) {
      lo = mid + 1;
    } else {
      hi = mid;
    }
  }
  const TfSample& after = sample(lo);
  if (after.stamp_ns == stamp_ns) {
    *T = to_se3(after);
    return TfAt::ready;
  }
  if (lo == 0) {
    if (!dropped_) return TfAt::none;  // before the edge's first transform
    *T = to_se3(after);
    *stale |= kTfHistoryShort;
    return TfAt::ready;
  }
  *T = blend(sample(lo - 1), after, stamp_ns);
  return TfAt::ready;
}

void TfBuffer::clear() {
  count_ = 0;
}

int TfBuffer::find(const char* name, std::size_t size) const {
  // TF names may start with a slash (ROS 1): "/world" and "world" are the same frame.
  if (size > 0 && name[0] == '/') {
    ++name;
    --size;
  }
  for (int i = 0; i < count_; ++i) {
    if (std::strlen(frames_[i].name) == size && std::strncmp(frames_[i].name, name, size) == 0) {
      return i;
    }
  }
  return -1;
}

int TfBuffer::find(const char* name, std::size_t size, bool insert) {
  const int found = static_cast<const TfBuffer*>(this)->find(name, size);
  if (found >= 0 || !insert) return found;
  if (size > 0 && name[0] == '/') {
    ++name;
    --size;
  }
  if (count_ >= max_frames_ || size >= kMaxName) return -1;
  Frame& frame = frames_[count_];
  std::memcpy(frame.name, name, size);
  frame.name[size] = '\0';
  frame.parent = -1;
  frame.history.attach(samples_ + static_cast<std::size_t>(count_) * history_, history_);
  return count_++;
}

bool TfBuffer::add(const RosPose& transform, std::int64_t fallback_stamp_ns, bool is_static) {
  Se3d checked;
  if (!pose_to_se3(transform, &checked)) return false;
  const int child = find(transform.child_frame.data, transform.child_frame.size, true);
  const int parent = find(transform.parent_frame.data, transform.parent_frame.size, true);
  if (child < 0 || parent < 0 || child == parent) return false;
  Frame& frame = frames_[child];
  if (frame.parent != parent) {
    frame.history.clear();  // a new parent: the edge's past is another edge's
    frame.parent = parent;
  }
  TfSample s;
  s.stamp_ns = transform.stamp_ns != 0 ? transform.stamp_ns : fallback_stamp_ns;
  std::memcpy(s.t, transform.t, sizeof(s.t));
  std::memcpy(s.q, transform.q, sizeof(s.q));
  frame.history.push(s, is_static);
  return true;
}

TfAt TfBuffer::chain_at(int from, int to, std::int64_t stamp_ns, bool final, Se3d* T_to_from,
                        unsigned* stale) const {
  if (from < 0) return TfAt::none;
  Se3d T = Se3d::Identity();
  bool waiting = false;
  int f = from;
  for (int steps = 0; steps <= count_; ++steps) {
    if (f == to || (to < 0 && frames_[f].parent < 0)) {
      if (waiting) return TfAt::wait;
      *T_to_from = T;
      return TfAt::ready;
    }
    if (frames_[f].parent < 0) return TfAt::none;
    Se3d T_parent_child;
    const TfAt edge = frames_[f].history.at(stamp_ns, final, &T_parent_child, stale);
    if (edge == TfAt::none) return TfAt::none;
    if (edge == TfAt::wait) {
      waiting = true;  // walk on: the chain may still not reach `to`
    } else {
      T = T_parent_child * T;
    }
    f = frames_[f].parent;
  }
  return TfAt::none;  // a cycle
}

}  // namespace octofuse::replay
