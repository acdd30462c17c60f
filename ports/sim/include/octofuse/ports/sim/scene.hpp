#pragma once
// Analytic scenes: a union of solid primitives with exact ray intersection and an exact signed
// distance. The rendered surface is the first entry into the union and the scene distance is the
// minimum over the primitives' exact distances, so both describe the same surface: a point the
// renderer returns has distance_m() == 0 up to rounding.
//
// World frame W: metres, z up. Every primitive has its own frame P (R_W_P, t_W_P).

#include <cstddef>
#include <cstdint>

#include <Eigen/Core>

#include "octofuse/core/fixed_vector.hpp"
#include "octofuse/core/status.hpp"

namespace octofuse::sim {

enum class PrimitiveKind : std::uint8_t {
  plane,     // solid below local z = 0 (outward normal +z_P); infinite
  box,       // |x_P|, |y_P|, |z_P| <= half_extents_m
  sphere,    // |p_P| <= radius_m
  capsule,   // within radius_m of the segment z_P in [-half_length_m, half_length_m]
  cylinder,  // capped: x_P^2 + y_P^2 <= radius_m^2, |z_P| <= half_length_m
};

// What a primitive stands for; thin structures are the ones whose recall is worth measuring.
enum class Part : std::uint8_t {
  structure,   // walls, floor, furniture bodies
  mug_handle,  // thin
  cable,       // thin
  key_cap,     // small relief on the keyboard
  chair_bar,   // thin
};
using PartMask = std::uint32_t;
constexpr PartMask part_bit(Part part) {
  return PartMask{1} << static_cast<unsigned>(part);
}
inline constexpr PartMask kThinParts =
    part_bit(Part::mug_handle) | part_bit(Part::cable) | part_bit(Part::chair_bar);
inline constexpr PartMask kAllParts = ~PartMask{0};

struct Primitive {
  PrimitiveKind kind = PrimitiveKind::sphere;
  Part part = Part::structure;
  Eigen::Matrix3d R_W_P = Eigen::Matrix3d::Identity();
  Eigen::Vector3d t_W_P = Eigen::Vector3d::Zero();           // centre (plane: a point on it)
  Eigen::Vector3d half_extents_m = Eigen::Vector3d::Zero();  // box
  double radius_m = 0.0;                                     // sphere, capsule, cylinder
  double half_length_m = 0.0;                                // capsule, cylinder
  // World-space bounds for culling; planes are unbounded.
  Eigen::Vector3d aabb_min_W = Eigen::Vector3d::Zero();
  Eigen::Vector3d aabb_max_W = Eigen::Vector3d::Zero();

  bool bounded() const { return kind != PrimitiveKind::plane; }
  bool thin() const { return (part_bit(part) & kThinParts) != 0; }

  // Exact signed distance of a point in the primitive frame (negative inside).
  double distance_local_m(const Eigen::Vector3d& p_P) const;
  double distance_m(const Eigen::Vector3d& p_W) const {
    return distance_local_m(R_W_P.transpose() * (p_W - t_W_P));
  }
  // First entry of the ray o_P + t d_P (d_P unit length) into the solid with t > 0. Origins
  // inside the solid see no surface. On a hit writes t (metres) and |cos| between the ray and
  // the surface normal.
  bool intersect_local(const Eigen::Vector3d& o_P, const Eigen::Vector3d& d_P, double* t_m,
                       double* cos_incidence) const;
  // Surface area (planes: 0, they are not sampled).
  double area_m2() const;
};

// Constructors; every size must be finite and > 0 (checked by Scene::add).
Primitive make_plane(const Eigen::Vector3d& point_W, const Eigen::Vector3d& normal_W);
Primitive make_box(const Eigen::Vector3d& centre_W, const Eigen::Vector3d& half_extents_m,
                   const Eigen::Matrix3d& R_W_P = Eigen::Matrix3d::Identity());
Primitive make_sphere(const Eigen::Vector3d& centre_W, double radius_m);
Primitive make_capsule(const Eigen::Vector3d& a_W, const Eigen::Vector3d& b_W, double radius_m);
Primitive make_cylinder(const Eigen::Vector3d& a_W, const Eigen::Vector3d& b_W, double radius_m);

class Scene {
 public:
  static constexpr std::size_t kMaxPrimitives = 256;

  // Adds `primitive` tagged with `part`. Returns ok, invalid_argument (a size not finite and
  // > 0, a rotation that is not one), resource_exhausted (kMaxPrimitives reached).
  Status add(Primitive primitive, Part part = Part::structure);
  void clear() { primitives_.clear(); }

  // Exact signed distance to the surface of the union (metres, negative inside).
  double distance_m(const Eigen::Vector3d& p_W) const;

  // First surface along o_W + t d_W, d_W unit length, t in (0, t_max_m]. Brute force over every
  // primitive: the renderer culls, this is the reference. Returns the primitive index or -1.
  int intersect(const Eigen::Vector3d& o_W, const Eigen::Vector3d& d_W, double t_max_m, double* t_m,
                double* cos_incidence) const;

  // Up to `capacity` points spread uniformly (by area) over the surfaces of primitives whose
  // part is in `parts`, keeping only points on the union's surface (not buried in another
  // primitive). Deterministic for a seed. Returns how many were written.
  std::size_t sample_surface(PartMask parts, std::uint64_t seed, Eigen::Vector3d* points_W,
                             std::size_t capacity) const;

  std::size_t size() const { return primitives_.size(); }
  const Primitive& operator[](std::size_t i) const { return primitives_[i]; }
  const Primitive* begin() const { return primitives_.begin(); }
  const Primitive* end() const { return primitives_.end(); }

 private:
  FixedVector<Primitive, kMaxPrimitives> primitives_;
};

}  // namespace octofuse::sim
