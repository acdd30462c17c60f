#pragma once
// A bag's TF tree over time, for the pose of each depth image at its own header stamp.
//
// Each edge (a child frame and its parent) keeps its newest transforms, sorted by stamp, in a
// fixed ring (TfHistory). A pose at time t chains the edges from a frame up to another, each
// taken at t: the transform stamped t as it is, else the two around t blended (translation
// linearly, rotation by slerp). Static edges (/tf_static) hold one transform for all times.
// Nothing is extrapolated: an edge whose newest transform is older than t says `wait` until the
// stream ends, then gives its newest transform, flagged; a t older than what the ring still holds
// gives the oldest, flagged; a t before an edge's first transform ever has no pose.
// All memory comes from the caller's arena at reserve(); nothing is allocated afterwards.

#include <cstddef>
#include <cstdint>

#include "octofuse/core/result.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/math/se3.hpp"
#include "octofuse/ports/replay/ros_messages.hpp"

namespace octofuse::replay {

struct TfSample {
  std::int64_t stamp_ns = 0;
  double t[3] = {};
  double q[4] = {0, 0, 0, 1};  // x y z w, as the message gave it (normalised when used)
};

enum class TfAt : std::uint8_t {
  ready,  // the transform at the time (maybe flagged, see TfStale)
  wait,   // not yet: no transform at or after the time has been read
  none,   // no transform for that time (none read, or the time is before the first)
};

// Why a ready transform is not the one at the time (bits).
enum TfStale : unsigned {
  kTfExact = 0,
  kTfPastEnd = 1,       // the stream ended before a transform at or after the time
  kTfHistoryShort = 2,  // the time is older than the ring still holds
};

class TfHistory {
 public:
  void attach(TfSample* samples, int capacity);
  void clear();
  // Adds a transform, in stamp order (a stamp already held is replaced). Static: the only one.
  void push(const TfSample& sample, bool is_static);
  // The transform at `stamp_ns`; `final`: the stream has ended (no later transform will come).
  TfAt at(std::int64_t stamp_ns, bool final, Se3d* T, unsigned* stale) const;

  int size() const { return count_; }
  bool is_static() const { return static_; }

 private:
  const TfSample& sample(int i) const { return samples_[(first_ + i) % capacity_]; }
  TfSample& sample(int i) { return samples_[(first_ + i) % capacity_]; }

  TfSample* samples_ = nullptr;
  int capacity_ = 0;
  int first_ = 0;
  int count_ = 0;
  bool static_ = false;
  bool dropped_ = false;  // older transforms fell out of the ring
};

class TfBuffer {
 public:
  static constexpr std::size_t kMaxName = 64;

  // Storage for `max_frames` frames with `history` transforms each, from `arena` (an ArenaSizer
  // to count it, then the LinearArena of the same size).
  template <typename Arena>
  Status reserve(Arena& arena, int max_frames, int history) {
    Result<Frame*> frames =
        arena.template allocate_array<Frame>(static_cast<std::size_t>(max_frames));
    if (!frames.ok()) return frames.status();
    Result<TfSample*> samples = arena.template allocate_array<TfSample>(
        static_cast<std::size_t>(max_frames) * static_cast<std::size_t>(history));
    if (!samples.ok()) return samples.status();
    frames_ = frames.value();
    samples_ = samples.value();
    max_frames_ = max_frames;
    history_ = history;
    clear();
    return ok_status();
  }
  void clear();

  // A frame's index by name ("/world" and "world" are the same frame); -1 when unknown (or, with
  // `insert`, when the table is full or the name too long).
  int find(const char* name, std::size_t size, bool insert);
  int find(const char* name, std::size_t size) const;
  // A geometry_msgs/TransformStamped; stamp 0 takes `fallback_stamp_ns` (the message's log time).
  // false when it is not a rigid transform or names no frames it can hold.
  bool add(const RosPose& transform, std::int64_t fallback_stamp_ns, bool is_static);

  // T_to_from at `stamp_ns`, chaining the edges from `from` up to `to` (-1: the root of from's
  // chain). none when the chain does not reach `to`; wait while an edge's transforms have not
  // reached the time and `final` is false. `stale` gathers the TfStale bits of the edges.
  TfAt chain_at(int from, int to, std::int64_t stamp_ns, bool final, Se3d* T_to_from,
                unsigned* stale) const;

  int count() const { return count_; }
  int parent(int frame) const { return frames_[frame].parent; }
  const char* name(int frame) const { return frames_[frame].name; }

 private:
  struct Frame {
    char name[kMaxName] = {};
    int parent = -1;
    TfHistory history;  // of the edge parent -> this frame
  };

  Frame* frames_ = nullptr;
  TfSample* samples_ = nullptr;
  int max_frames_ = 0;
  int history_ = 0;
  int count_ = 0;
};

}  // namespace octofuse::replay
