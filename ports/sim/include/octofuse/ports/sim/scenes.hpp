#pragma once
// The built-in worlds: a scene plus the camera path through it, with exact ground truth.
//   desk  a desk with a keyboard (key caps), a mug with a 5 mm handle, cables, a chair with thin
//         bars; seen first from 0.4-0.6 m, then the camera pulls back to 2-3 m (the paper's
//         close-then-far case). 300 frames by default.
//   room  a 6 x 5 x 2.7 m room with furniture, one orbit at 1.8 m radius. 360 frames by default.

#include <cstddef>
#include <cstdint>

#include <Eigen/Core>

#include "octofuse/core/fixed_vector.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/math/se3.hpp"
#include "octofuse/ports/sim/scene.hpp"

namespace octofuse::sim {

enum class SceneId : std::uint8_t { desk, room };

// "desk" or "room" -> id; returns invalid_argument for anything else.
Status scene_id_from_name(const char* name, SceneId* id);
const char* scene_name(SceneId id);

// Camera at eye_W looking at target_W, world up +z (optical frame: x right, y down, z forward).
// eye and target must differ and not be vertically aligned.
Se3d look_at(const Eigen::Vector3d& eye_W, const Eigen::Vector3d& target_W);

// A smooth path: Catmull-Rom splines through eye and target waypoints, evenly spaced in time.
class CameraPath {
 public:
  static constexpr std::size_t kMaxWaypoints = 32;
  struct Waypoint {
    Eigen::Vector3d eye_W;
    Eigen::Vector3d target_W;
  };

  Status add(const Eigen::Vector3d& eye_W, const Eigen::Vector3d& target_W) {
    return waypoints_.push_back(Waypoint{eye_W, target_W});
  }
  // Pose at s in [0, 1] (clamped): s = 0 at the first waypoint, 1 at the last.
  Se3d T_W_C(double s) const;
  std::size_t size() const { return waypoints_.size(); }

 private:
  FixedVector<Waypoint, kMaxWaypoints> waypoints_;
};

struct SimWorld {
  Scene scene;
  CameraPath path;
  int default_frame_count = 300;
};

// Fills `world` (cleared first). Returns ok or internal (a built-in scene outgrew its capacity).
Status build_world(SceneId id, SimWorld* world);

}  // namespace octofuse::sim
