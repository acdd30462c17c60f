#include "octofuse/ports/sim/scene.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/Geometry>
#include <Eigen/LU>
#include <limits>

#include "dot3.hpp"
#include "octofuse/ports/sim/random.hpp"

namespace octofuse::sim {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kInfinity = std::numeric_limits<double>::infinity();
constexpr double kParallelEpsilon = 1e-12;  // direction components below this count as zero

// Rotation whose z axis is `axis` (unit); the other two axes are any orthonormal completion.
Eigen::Matrix3d frame_with_z(const Eigen::Vector3d& axis) {
  const Eigen::Vector3d helper =
      std::abs(axis.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  const Eigen::Vector3d x = helper.cross(axis).normalized();
  const Eigen::Vector3d y = axis.cross(x);
  Eigen::Matrix3d R;
  R.col(0) = x;
  R.col(1) = y;
  R.col(2) = axis;
  return R;
}

void set_bounds(Primitive* p) {
  Eigen::Vector3d local_half = Eigen::Vector3d::Zero();  // every valid kind sets it below
  switch (p->kind) {
    case PrimitiveKind::plane:
      p->aabb_min_W = Eigen::Vector3d::Constant(-kInfinity);
      p->aabb_max_W = Eigen::Vector3d::Constant(kInfinity);
      return;
    case PrimitiveKind::box:
      local_half = p->half_extents_m;
      break;
    case PrimitiveKind::sphere:
      local_half = Eigen::Vector3d::Constant(p->radius_m);
      break;
    case PrimitiveKind::capsule:
      local_half = Eigen::Vector3d(p->radius_m, p->radius_m, p->half_length_m + p->radius_m);
      break;
    case PrimitiveKind::cylinder:
      local_half = Eigen::Vector3d(p->radius_m, p->radius_m, p->half_length_m);
      break;
  }
  // Bounds of a rotated box: |R| times the half extents.
  const Eigen::Vector3d half_W = p->R_W_P.cwiseAbs() * local_half;
  p->aabb_min_W = p->t_W_P - half_W;
  p->aabb_max_W = p->t_W_P + half_W;
}

// The ray tests below are scalar code built on dot3() (see dot3.hpp for why).

// Entry of a ray into a sphere of radius r centred at (0, 0, c_z) (in the same frame as o).
bool sphere_entry(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double c_z, double r,
                  double* t) {
  const double dx = d.x();
  const double dy = d.y();
  const double dz = d.z();
  const double ocx = o.x();  // x - 0 is x, bit for bit
  const double ocy = o.y();
  const double ocz = o.z() - c_z;
  const double t_closest = -dot3(ocx, ocy, ocz, dx, dy, dz);
  // Closest approach; no cancellation.
  const double qx = ocx + t_closest * dx;
  const double qy = ocy + t_closest * dy;
  const double qz = ocz + t_closest * dz;
  const double h2 = r * r - dot3(qx, qy, qz, qx, qy, qz);
  if (h2 < 0.0) return false;
  const double t_entry = t_closest - std::sqrt(h2);
  if (t_entry <= 0.0) return false;
  *t = t_entry;
  return true;
}

// Entry through the side of the infinite cylinder x^2 + y^2 = r^2; returns the 2-D offset of the
// closest approach for the normal.
bool side_entry(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double r, double* t) {
  const double a = d.x() * d.x() + d.y() * d.y();
  if (a < kParallelEpsilon) return false;
  const double t_closest = -(o.x() * d.x() + o.y() * d.y()) / a;
  const double qx = o.x() + t_closest * d.x();
  const double qy = o.y() + t_closest * d.y();
  const double h2 = r * r - (qx * qx + qy * qy);
  if (h2 < 0.0) return false;
  const double t_entry = t_closest - std::sqrt(h2 / a);
  if (t_entry <= 0.0) return false;
  *t = t_entry;
  return true;
}

}  // namespace

double Primitive::distance_local_m(const Eigen::Vector3d& p) const {
  switch (kind) {
    case PrimitiveKind::plane:
      return p.z();
    case PrimitiveKind::box: {
      const Eigen::Vector3d q = p.cwiseAbs() - half_extents_m;
      return q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0);
    }
    case PrimitiveKind::sphere:
      return p.norm() - radius_m;
    case PrimitiveKind::capsule: {
      const double z = std::clamp(p.z(), -half_length_m, half_length_m);
      return Eigen::Vector3d(p.x(), p.y(), p.z() - z).norm() - radius_m;
    }
    case PrimitiveKind::cylinder: {
      const double dr = std::hypot(p.x(), p.y()) - radius_m;
      const double dz = std::abs(p.z()) - half_length_m;
      return std::min(std::max(dr, dz), 0.0) + std::hypot(std::max(dr, 0.0), std::max(dz, 0.0));
    }
  }
  return kInfinity;
}

bool Primitive::intersect_local(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double* t_m,
                                double* cos_incidence) const {
  switch (kind) {
    case PrimitiveKind::plane: {
      if (o.z() <= 0.0 || d.z() >= 0.0) return false;
      *t_m = -o.z() / d.z();
      *cos_incidence = -d.z();
      return true;
    }
    case PrimitiveKind::box: {
      double t_near = -kInfinity;
      double t_far = kInfinity;
      int axis_near = 0;
      // Raw arrays: no index check per access in a debug (sanitizer) build.
      const double* const o_i = o.data();
      const double* const d_i = d.data();
      const double* const h_i = half_extents_m.data();
      for (int i = 0; i < 3; ++i) {
        const double h = h_i[i];
        if (std::abs(d_i[i]) < kParallelEpsilon) {
          if (std::abs(o_i[i]) > h) return false;
          continue;
        }
        const double inv = 1.0 / d_i[i];
        double t0 = (-h - o_i[i]) * inv;
        double t1 = (h - o_i[i]) * inv;
        if (t0 > t1) std::swap(t0, t1);
        if (t0 > t_near) {
          t_near = t0;
          axis_near = i;
        }
        t_far = std::min(t_far, t1);
      }
      if (t_near > t_far || t_near <= 0.0) return false;
      *t_m = t_near;
      *cos_incidence = std::abs(d_i[axis_near]);
      return true;
    }
    case PrimitiveKind::sphere: {
      double t;
      if (!sphere_entry(o, d, 0.0, radius_m, &t)) return false;
      *t_m = t;
      const double px = o.x() + t * d.x();
      const double py = o.y() + t * d.y();
      const double pz = o.z() + t * d.z();
      *cos_incidence = std::abs(dot3(px, py, pz, d.x(), d.y(), d.z())) / radius_m;
      return true;
    }
    case PrimitiveKind::capsule: {
      double best = kInfinity;
      double nx = 0.0;
      double ny = 0.0;
      double nz = 0.0;
      double t;
      if (side_entry(o, d, radius_m, &t) && std::abs(o.z() + t * d.z()) <= half_length_m) {
        best = t;
        nx = o.x() + t * d.x();
        ny = o.y() + t * d.y();
        nz = 0.0;
      }
      for (const double end_z : {-half_length_m, half_length_m}) {
        if (sphere_entry(o, d, end_z, radius_m, &t) && t < best) {
          best = t;
          nx = o.x() + t * d.x();
          ny = o.y() + t * d.y();
          nz = (o.z() + t * d.z()) - end_z;
        }
      }
      if (best == kInfinity) return false;
      *t_m = best;
      *cos_incidence = std::min(1.0, std::abs(dot3(nx, ny, nz, d.x(), d.y(), d.z())) / radius_m);
      return true;
    }
    case PrimitiveKind::cylinder: {
      if (std::abs(o.z()) <= half_length_m &&
          o.x() * o.x() + o.y() * o.y() <= radius_m * radius_m) {
        return false;  // inside
      }
      double best = kInfinity;
      double cos_best = 0.0;
      double t;
      if (side_entry(o, d, radius_m, &t) && std::abs(o.z() + t * d.z()) <= half_length_m) {
        best = t;
        const double nx = o.x() + t * d.x();
        const double ny = o.y() + t * d.y();
        cos_best = std::min(1.0, std::abs(nx * d.x() + ny * d.y()) / radius_m);
      }
      if (std::abs(d.z()) >= kParallelEpsilon) {
        // Only the cap facing the origin can be an entry.
        const double cap_z = o.z() > 0.0 ? half_length_m : -half_length_m;
        const double t_cap = (cap_z - o.z()) / d.z();
        if (t_cap > 0.0 && t_cap < best) {
          const double x = o.x() + t_cap * d.x();
          const double y = o.y() + t_cap * d.y();
          if (x * x + y * y <= radius_m * radius_m) {
            best = t_cap;
            cos_best = std::abs(d.z());
          }
        }
      }
      if (best == kInfinity) return false;
      *t_m = best;
      *cos_incidence = cos_best;
      return true;
    }
  }
  return false;
}

double Primitive::area_m2() const {
  const double r = radius_m;
  const double L = 2.0 * half_length_m;
  switch (kind) {
    case PrimitiveKind::plane:
      return 0.0;
    case PrimitiveKind::box: {
      const Eigen::Vector3d e = 2.0 * half_extents_m;
      return 2.0 * (e.x() * e.y() + e.y() * e.z() + e.x() * e.z());
    }
    case PrimitiveKind::sphere:
      return 4.0 * kPi * r * r;
    case PrimitiveKind::capsule:
      return 2.0 * kPi * r * L + 4.0 * kPi * r * r;
    case PrimitiveKind::cylinder:
      return 2.0 * kPi * r * L + 2.0 * kPi * r * r;
  }
  return 0.0;
}

Primitive make_plane(const Eigen::Vector3d& point_W, const Eigen::Vector3d& normal_W) {
  Primitive p;
  p.kind = PrimitiveKind::plane;
  p.R_W_P = frame_with_z(normal_W.normalized());
  p.t_W_P = point_W;
  return p;
}

Primitive make_box(const Eigen::Vector3d& centre_W, const Eigen::Vector3d& half_extents_m,
                   const Eigen::Matrix3d& R_W_P) {
  Primitive p;
  p.kind = PrimitiveKind::box;
  p.R_W_P = R_W_P;
  p.t_W_P = centre_W;
  p.half_extents_m = half_extents_m;
  return p;
}

Primitive make_sphere(const Eigen::Vector3d& centre_W, double radius_m) {
  Primitive p;
  p.kind = PrimitiveKind::sphere;
  p.t_W_P = centre_W;
  p.radius_m = radius_m;
  return p;
}

namespace {
Primitive make_segment_solid(PrimitiveKind kind, const Eigen::Vector3d& a_W,
                             const Eigen::Vector3d& b_W, double radius_m) {
  Primitive p;
  p.kind = kind;
  const Eigen::Vector3d axis = b_W - a_W;
  p.half_length_m = 0.5 * axis.norm();
  p.R_W_P = frame_with_z(p.half_length_m > 0.0 ? Eigen::Vector3d(axis.normalized())
                                               : Eigen::Vector3d::UnitZ());
  p.t_W_P = 0.5 * (a_W + b_W);
  p.radius_m = radius_m;
  return p;
}
}  // namespace

Primitive make_capsule(const Eigen::Vector3d& a_W, const Eigen::Vector3d& b_W, double radius_m) {
  return make_segment_solid(PrimitiveKind::capsule, a_W, b_W, radius_m);
}

Primitive make_cylinder(const Eigen::Vector3d& a_W, const Eigen::Vector3d& b_W, double radius_m) {
  return make_segment_solid(PrimitiveKind::cylinder, a_W, b_W, radius_m);
}

Status Scene::add(Primitive primitive, Part part) {
  const auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
  bool sizes_ok = primitive.t_W_P.allFinite() && primitive.R_W_P.allFinite();
  switch (primitive.kind) {
    case PrimitiveKind::plane:
      break;
    case PrimitiveKind::box:
      sizes_ok = sizes_ok && positive(primitive.half_extents_m.x()) &&
                 positive(primitive.half_extents_m.y()) && positive(primitive.half_extents_m.z());
      break;
    case PrimitiveKind::sphere:
      sizes_ok = sizes_ok && positive(primitive.radius_m);
      break;
    case PrimitiveKind::capsule:
    case PrimitiveKind::cylinder:
      sizes_ok = sizes_ok && positive(primitive.radius_m) && positive(primitive.half_length_m);
      break;
  }
  if (!sizes_ok) return StatusCode::invalid_argument;
  const Eigen::Matrix3d& R = primitive.R_W_P;
  constexpr double kRotationTolerance = 1e-9;
  if ((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() >
          kRotationTolerance ||
      std::abs(R.determinant() - 1.0) > kRotationTolerance) {
    return StatusCode::invalid_argument;
  }
  primitive.part = part;
  set_bounds(&primitive);
  return primitives_.push_back(primitive);
}

double Scene::distance_m(const Eigen::Vector3d& p_W) const {
  double best = kInfinity;
  for (const Primitive& p : primitives_) best = std::min(best, p.distance_m(p_W));
  return best;
}

int Scene::intersect(const Eigen::Vector3d& o_W, const Eigen::Vector3d& d_W, double t_max_m,
                     double* t_m, double* cos_incidence) const {
  int hit = -1;
  double best = t_max_m;
  for (std::size_t i = 0; i < primitives_.size(); ++i) {
    const Primitive& p = primitives_[i];
    double t;
    double c;
    if (p.intersect_local(p.R_W_P.transpose() * (o_W - p.t_W_P), p.R_W_P.transpose() * d_W, &t,
                          &c) &&
        t <= best) {
      best = t;
      hit = static_cast<int>(i);
      *t_m = t;
      *cos_incidence = c;
    }
  }
  return hit;
}

namespace {

// A point uniformly on the surface of `p` (bounded kinds), in the primitive frame.
Eigen::Vector3d sample_local(const Primitive& p, SplitMix64& rng) {
  const double u0 = rng.uniform();
  const double u1 = rng.uniform();
  const double u2 = rng.uniform();
  const auto on_sphere = [](double a, double b) {
    const double z = 2.0 * a - 1.0;
    const double rho = std::sqrt(std::max(0.0, 1.0 - z * z));
    const double phi = 2.0 * kPi * b;
    return Eigen::Vector3d(rho * std::cos(phi), rho * std::sin(phi), z);
  };
  const double r = p.radius_m;
  const double L = p.half_length_m;
  switch (p.kind) {
    case PrimitiveKind::plane:
      return Eigen::Vector3d::Zero();
    case PrimitiveKind::box: {
      const Eigen::Vector3d e = p.half_extents_m;
      const double areas[3] = {e.y() * e.z(), e.x() * e.z(), e.x() * e.y()};
      double pick = u0 * (areas[0] + areas[1] + areas[2]);
      int axis = 0;
      while (axis < 2 && pick > areas[axis]) pick -= areas[axis++];
      Eigen::Vector3d q;
      const int a1 = (axis + 1) % 3;
      const int a2 = (axis + 2) % 3;
      q[axis] = rng.uniform() < 0.5 ? -e[axis] : e[axis];
      q[a1] = (2.0 * u1 - 1.0) * e[a1];
      q[a2] = (2.0 * u2 - 1.0) * e[a2];
      return q;
    }
    case PrimitiveKind::sphere:
      return r * on_sphere(u1, u2);
    case PrimitiveKind::capsule: {
      const double side = 2.0 * kPi * r * 2.0 * L;
      if (u0 * p.area_m2() < side) {
        const double phi = 2.0 * kPi * u1;
        return Eigen::Vector3d(r * std::cos(phi), r * std::sin(phi), (2.0 * u2 - 1.0) * L);
      }
      Eigen::Vector3d q = r * on_sphere(u1, u2);
      q.z() += q.z() >= 0.0 ? L : -L;
      return q;
    }
    case PrimitiveKind::cylinder: {
      const double side = 2.0 * kPi * r * 2.0 * L;
      const double phi = 2.0 * kPi * u1;
      if (u0 * p.area_m2() < side) {
        return Eigen::Vector3d(r * std::cos(phi), r * std::sin(phi), (2.0 * u2 - 1.0) * L);
      }
      const double rho = r * std::sqrt(u2);
      return Eigen::Vector3d(rho * std::cos(phi), rho * std::sin(phi),
                             rng.uniform() < 0.5 ? -L : L);
    }
  }
  return Eigen::Vector3d::Zero();
}

}  // namespace

std::size_t Scene::sample_surface(PartMask parts, std::uint64_t seed, Eigen::Vector3d* points_W,
                                  std::size_t capacity) const {
  double total_area = 0.0;
  for (const Primitive& p : primitives_) {
    if ((part_bit(p.part) & parts) != 0) total_area += p.area_m2();
  }
  if (total_area <= 0.0 || points_W == nullptr) return 0;
  // Points buried inside another primitive are not on the surface anyone can see or rebuild.
  constexpr double kBuriedTolerance_m = 1e-9;
  SplitMix64 rng(seed);
  std::size_t count = 0;
  for (std::size_t attempt = 0; attempt < capacity; ++attempt) {
    double pick = rng.uniform() * total_area;
    std::size_t chosen = primitives_.size();
    for (std::size_t i = 0; i < primitives_.size(); ++i) {
      const Primitive& p = primitives_[i];
      if ((part_bit(p.part) & parts) == 0) continue;
      chosen = i;
      pick -= p.area_m2();
      if (pick <= 0.0) break;
    }
    const Primitive& p = primitives_[chosen];
    const Eigen::Vector3d p_W = p.R_W_P * sample_local(p, rng) + p.t_W_P;
    if (distance_m(p_W) >= -kBuriedTolerance_m) points_W[count++] = p_W;
  }
  return count;
}

}  // namespace octofuse::sim
