#include "octofuse/ports/sim/scenes.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>

namespace octofuse::sim {
namespace {

using V3 = Eigen::Vector3d;
constexpr double kPi = 3.14159265358979323846;

Eigen::Matrix3d yaw(double radians) {
  return Eigen::AngleAxisd(radians, V3::UnitZ()).toRotationMatrix();
}

// Collects the first failure so builders read as a list of shapes.
class Builder {
 public:
  explicit Builder(SimWorld* world) : world_(world) {}
  void add(const Primitive& p, Part part = Part::structure) {
    const Status s = world_->scene.add(p, part);
    if (!s.ok() && status_.ok()) status_ = s;
  }
  // Capsules along a polyline: joints are shared spheres, so the tube is smooth and closed.
  void tube(const V3* points, int count, double radius_m, Part part) {
    for (int i = 0; i + 1 < count; ++i) add(make_capsule(points[i], points[i + 1], radius_m), part);
  }
  void waypoint(const V3& eye, const V3& target) {
    const Status s = world_->path.add(eye, target);
    if (!s.ok() && status_.ok()) status_ = s;
  }
  Status status() const { return status_.ok() ? status_ : Status(StatusCode::internal); }

 private:
  SimWorld* world_;
  Status status_;
};

// A chair with a seat at `centre` (floor contact), backrest towards -y before `yaw_rad`.
void add_chair(Builder& b, const V3& base_W, double yaw_rad) {
  const Eigen::Matrix3d R = yaw(yaw_rad);
  const auto at = [&](double x, double y, double z) { return V3(base_W + R * V3(x, y, z)); };
  constexpr double kSeatZ = 0.46;
  b.add(make_box(at(0.0, 0.0, kSeatZ), V3(0.22, 0.2, 0.025), R));
  constexpr double kLeg_m = 0.012;
  for (const double sx : {-0.18, 0.18}) {
    for (const double sy : {-0.16, 0.16}) {
      b.add(make_capsule(at(sx, sy, kSeatZ - 0.03), at(sx, sy, kLeg_m), kLeg_m), Part::chair_bar);
    }
    // Stretcher between front and back legs.
    b.add(make_capsule(at(sx, -0.16, 0.2), at(sx, 0.16, 0.2), 0.007), Part::chair_bar);
  }
  // Backrest: two posts, three rails, three slats.
  for (const double sx : {-0.19, 0.19}) {
    b.add(make_capsule(at(sx, -0.19, kSeatZ), at(sx, -0.21, 0.95), 0.011), Part::chair_bar);
  }
  for (const double z : {0.65, 0.8, 0.93}) {
    const double y = -0.19 - 0.02 * (z - kSeatZ) / (0.95 - kSeatZ);
    b.add(make_capsule(at(-0.19, y, z), at(0.19, y, z), 0.008), Part::chair_bar);
  }
  for (const double sx : {-0.09, 0.0, 0.09}) {
    b.add(make_capsule(at(sx, -0.198, 0.65), at(sx, -0.2055, 0.93), 0.006), Part::chair_bar);
  }
}

void build_desk(Builder& b) {
  // Room shell: floor, back wall, side walls.
  b.add(make_plane(V3(0, 0, 0), V3(0, 0, 1)));
  b.add(make_plane(V3(0, 0.8, 0), V3(0, -1, 0)));
  b.add(make_plane(V3(-1.8, 0, 0), V3(1, 0, 0)));
  b.add(make_plane(V3(2.2, 0, 0), V3(-1, 0, 0)));

  // Desk: top surface at z = 0.75.
  constexpr double kTop = 0.75;
  b.add(make_box(V3(0, 0, kTop - 0.015), V3(0.7, 0.35, 0.015)));
  for (const double x : {-0.65, 0.65}) {
    for (const double y : {-0.3, 0.3}) b.add(make_box(V3(x, y, 0.36), V3(0.025, 0.025, 0.36)));
  }

  // Monitor: foot, neck, screen.
  b.add(make_box(V3(0, 0.2, kTop + 0.005), V3(0.1, 0.08, 0.005)));
  b.add(make_box(V3(0, 0.22, 0.9), V3(0.025, 0.015, 0.15)));
  b.add(make_box(V3(0, 0.2, 1.0), V3(0.3, 0.015, 0.18)));

  // Keyboard: base and 4 x 12 key caps on a 19 mm pitch, plus a space bar.
  const V3 keyboard(-0.05, -0.12, kTop + 0.0075);
  b.add(make_box(keyboard, V3(0.22, 0.075, 0.0075)));
  constexpr double kPitch = 0.019;
  const double cap_z = kTop + 0.015 + 0.004;
  for (int row = 0; row < 4; ++row) {
    for (int col = 0; col < 12; ++col) {
      const V3 c(keyboard.x() + (col - 5.5) * kPitch, keyboard.y() + (row - 1.0) * kPitch, cap_z);
      b.add(make_box(c, V3(0.0075, 0.0075, 0.004)), Part::key_cap);
    }
  }
  b.add(make_box(V3(keyboard.x(), keyboard.y() - 2.0 * kPitch, cap_z), V3(0.05, 0.0075, 0.004)),
        Part::key_cap);

  // Mouse (half sunk into the desk) and its cable.
  b.add(make_capsule(V3(0.25, -0.15, kTop), V3(0.25, -0.1, kTop), 0.016));
  // Mug: body and a C-shaped handle 5 mm thick, in a plane through the mug's axis.
  const V3 mug(0.35, -0.05, kTop);
  b.add(make_cylinder(mug, mug + V3(0, 0, 0.095), 0.04));
  const V3 out = V3(1.0, -0.6, 0.0).normalized();
  const double handle[6][2] = {{0.038, 0.022}, {0.058, 0.022}, {0.068, 0.035},
                               {0.068, 0.062}, {0.058, 0.075}, {0.038, 0.075}};
  V3 handle_points[6];
  for (int i = 0; i < 6; ++i) handle_points[i] = mug + handle[i][0] * out + V3(0, 0, handle[i][1]);
  b.tube(handle_points, 6, 0.0025, Part::mug_handle);

  // Cables lying on the desk (6 mm and 5 mm) and one hanging to the floor (8 mm).
  constexpr int kCablePoints = 11;
  V3 cable[kCablePoints];
  for (int i = 0; i < kCablePoints; ++i) {
    const double s = static_cast<double>(i) / (kCablePoints - 1);
    const V3 along = (1.0 - s) * V3(0.05, 0.14, 0) + s * V3(-0.12, -0.035, 0);
    const V3 side = V3(0.72, 0.7, 0).normalized();
    cable[i] = along + 0.035 * std::sin(2.0 * kPi * s) * side + V3(0, 0, kTop + 0.003);
  }
  b.tube(cable, kCablePoints, 0.003, Part::cable);
  for (int i = 0; i < kCablePoints; ++i) {
    const double s = static_cast<double>(i) / (kCablePoints - 1);
    const V3 along = (1.0 - s) * V3(0.1, 0.14, 0) + s * V3(0.25, -0.08, 0);
    cable[i] = along + 0.03 * std::sin(1.5 * kPi * s) * V3(1, 0, 0) + V3(0, 0, kTop + 0.0025);
  }
  b.tube(cable, kCablePoints, 0.0025, Part::cable);
  const V3 hanging[5] = {V3(0.4, 0.25, kTop + 0.004), V3(0.41, 0.352, kTop + 0.004),
                         V3(0.42, 0.36, 0.6), V3(0.46, 0.4, 0.2), V3(0.55, 0.45, 0.004)};
  b.tube(hanging, 5, 0.004, Part::cable);

  // A book and a ball.
  b.add(make_box(V3(-0.45, 0.05, kTop + 0.025), V3(0.1, 0.14, 0.025), yaw(0.26)));
  b.add(make_sphere(V3(-0.45, -0.2, kTop + 0.04), 0.04));

  add_chair(b, V3(0.15, -0.62, 0.0), 0.0);

  // Close: over the keyboard, the mug and its handle, the cables; then back to 2-3 m.
  b.waypoint(V3(-0.2, -0.5, 1.1), V3(-0.1, -0.1, 0.77));
  b.waypoint(V3(0.0, -0.48, 1.08), V3(0.05, -0.08, 0.78));
  b.waypoint(V3(0.2, -0.45, 1.08), V3(0.3, -0.06, 0.8));
  b.waypoint(V3(0.45, -0.42, 1.05), V3(0.35, -0.04, 0.8));
  b.waypoint(V3(0.3, -0.35, 1.12), V3(0.15, 0.05, 0.8));
  b.waypoint(V3(0.1, -0.9, 1.3), V3(0.05, 0.0, 0.8));
  b.waypoint(V3(-0.1, -1.6, 1.5), V3(0.0, 0.0, 0.7));
  b.waypoint(V3(-0.4, -2.3, 1.6), V3(0.0, -0.1, 0.65));
  b.waypoint(V3(0.3, -2.5, 1.7), V3(0.1, -0.2, 0.6));
  b.waypoint(V3(1.0, -2.2, 1.6), V3(0.1, -0.1, 0.6));
  b.waypoint(V3(0.5, -2.3, 1.8), V3(0.0, 0.0, 0.6));
}

void build_room(Builder& b) {
  // A 6 x 5 x 2.7 m room.
  b.add(make_plane(V3(0, 0, 0), V3(0, 0, 1)));
  b.add(make_plane(V3(0, 0, 2.7), V3(0, 0, -1)));
  b.add(make_plane(V3(-3, 0, 0), V3(1, 0, 0)));
  b.add(make_plane(V3(3, 0, 0), V3(-1, 0, 0)));
  b.add(make_plane(V3(0, -2.5, 0), V3(0, 1, 0)));
  b.add(make_plane(V3(0, 2.5, 0), V3(0, -1, 0)));

  // Table in the middle with a lamp and a bowl.
  b.add(make_box(V3(0, 0, 0.73), V3(0.6, 0.4, 0.02)));
  for (const double x : {-0.55, 0.55}) {
    for (const double y : {-0.35, 0.35}) b.add(make_cylinder(V3(x, y, 0), V3(x, y, 0.71), 0.03));
  }
  b.add(make_cylinder(V3(0.2, 0.1, 0.75), V3(0.2, 0.1, 0.77), 0.08));
  b.add(make_capsule(V3(0.2, 0.1, 0.77), V3(0.2, 0.1, 1.0), 0.01), Part::chair_bar);
  b.add(make_sphere(V3(0.2, 0.1, 1.08), 0.1));
  b.add(make_sphere(V3(-0.25, -0.1, 0.75), 0.12));  // a bowl, half in the table

  add_chair(b, V3(0.0, -0.7, 0.0), 0.0);
  add_chair(b, V3(0.0, 0.7, 0.0), kPi);
  add_chair(b, V3(-0.95, 0.0, 0.0), -0.5 * kPi);

  // Sofa against the +y wall.
  b.add(make_box(V3(0.5, 2.05, 0.22), V3(1.0, 0.4, 0.22)));
  b.add(make_box(V3(0.5, 2.38, 0.55), V3(1.0, 0.12, 0.33)));
  for (const double x : {-0.45, 1.45}) b.add(make_box(V3(x, 2.05, 0.32), V3(0.1, 0.4, 0.32)));

  // Shelf against the -x wall: two sides, four boards, some books.
  for (const double y : {-1.0, 0.0}) b.add(make_box(V3(-2.8, y, 1.0), V3(0.18, 0.015, 1.0)));
  for (int i = 0; i < 4; ++i) {
    b.add(make_box(V3(-2.8, -0.5, 0.3 + 0.5 * i), V3(0.18, 0.485, 0.012)));
  }
  for (int i = 0; i < 6; ++i) {
    const double h = 0.1 + 0.02 * (i % 3);
    b.add(make_box(V3(-2.82, -0.85 + 0.12 * i, 0.812 + h), V3(0.1, 0.03, h)));
  }

  // Cabinet against +x, a pillar, a bin, a floor lamp.
  b.add(make_box(V3(2.7, -1.0, 0.45), V3(0.3, 0.6, 0.45)));
  b.add(make_box(V3(2.5, 1.8, 1.35), V3(0.25, 0.25, 1.35)));
  b.add(make_cylinder(V3(1.6, -1.9, 0), V3(1.6, -1.9, 0.4), 0.15));
  b.add(make_cylinder(V3(-2.2, 1.9, 0), V3(-2.2, 1.9, 0.03), 0.18));
  b.add(make_capsule(V3(-2.2, 1.9, 0.03), V3(-2.2, 1.9, 1.6), 0.012), Part::chair_bar);
  b.add(make_sphere(V3(-2.2, 1.9, 1.72), 0.16));

  // One orbit at 1.8 m radius, 1.5 m up, looking at the table; 13 waypoints close the loop.
  constexpr int kSteps = 12;
  for (int i = 0; i <= kSteps; ++i) {
    const double a = 2.0 * kPi * i / kSteps - 0.5 * kPi;
    const V3 eye(1.8 * std::cos(a), 1.8 * std::sin(a), 1.5 + 0.1 * std::sin(2.0 * a));
    b.waypoint(eye, V3(0.2 * std::cos(a + 0.6), 0.2 * std::sin(a + 0.6), 0.7));
  }
}

V3 catmull_rom(const V3& p0, const V3& p1, const V3& p2, const V3& p3, double t) {
  const double t2 = t * t;
  const double t3 = t2 * t;
  return 0.5 * ((2.0 * p1) + (p2 - p0) * t + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * t2 +
                (3.0 * p1 - p0 - 3.0 * p2 + p3) * t3);
}

}  // namespace

Status scene_id_from_name(const char* name, SceneId* id) {
  if (name == nullptr || id == nullptr) return StatusCode::invalid_argument;
  if (std::strcmp(name, "desk") == 0) {
    *id = SceneId::desk;
  } else if (std::strcmp(name, "room") == 0) {
    *id = SceneId::room;
  } else {
    return StatusCode::invalid_argument;
  }
  return ok_status();
}

const char* scene_name(SceneId id) {
  switch (id) {
    case SceneId::desk:
      return "desk";
    case SceneId::room:
      return "room";
  }
  return "unknown";
}

Se3d look_at(const Eigen::Vector3d& eye_W, const Eigen::Vector3d& target_W) {
  const V3 z = (target_W - eye_W).normalized();
  const V3 x = z.cross(V3::UnitZ()).normalized();
  const V3 y = z.cross(x);
  Se3d T = Se3d::Identity();
  T.linear().col(0) = x;
  T.linear().col(1) = y;
  T.linear().col(2) = z;
  T.translation() = eye_W;
  return T;
}

Se3d CameraPath::T_W_C(double s) const {
  const std::size_t n = waypoints_.size();
  if (n == 0) return Se3d::Identity();
  if (n == 1) return look_at(waypoints_[0].eye_W, waypoints_[0].target_W);
  const double position = std::clamp(s, 0.0, 1.0) * static_cast<double>(n - 1);
  const std::size_t i = std::min(static_cast<std::size_t>(position), n - 2);
  const double t = position - static_cast<double>(i);
  const std::size_t i0 = i == 0 ? 0 : i - 1;
  const std::size_t i3 = std::min(i + 2, n - 1);
  const V3 eye = catmull_rom(waypoints_[i0].eye_W, waypoints_[i].eye_W, waypoints_[i + 1].eye_W,
                             waypoints_[i3].eye_W, t);
  const V3 target = catmull_rom(waypoints_[i0].target_W, waypoints_[i].target_W,
                                waypoints_[i + 1].target_W, waypoints_[i3].target_W, t);
  return look_at(eye, target);
}

Status build_world(SceneId id, SimWorld* world) {
  if (world == nullptr) return StatusCode::invalid_argument;
  world->scene.clear();
  world->path = CameraPath();
  Builder builder(world);
  switch (id) {
    case SceneId::desk:
      build_desk(builder);
      world->default_frame_count = 300;
      break;
    case SceneId::room:
      build_room(builder);
      world->default_frame_count = 360;
      break;
  }
  return builder.status();
}

}  // namespace octofuse::sim
