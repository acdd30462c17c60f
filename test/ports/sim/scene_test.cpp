#include "octofuse/ports/sim/scene.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <vector>

#include <Eigen/Geometry>

#include "octofuse/ports/sim/random.hpp"

namespace octofuse::sim {
namespace {

using V3 = Eigen::Vector3d;
constexpr double kExact_m = 1e-12;
constexpr double kSurface_m = 1e-9;  // hit points lie on the exact surface up to rounding
constexpr double kTraceAgreement_m = 1e-6;

TEST_CASE("a ray meets each primitive at the known distance") {
  double t = 0.0;
  double c = 0.0;
  SECTION("plane") {
    const Primitive p = make_plane(V3(0, 0, 1), V3(0, 0, 1));
    REQUIRE(p.intersect_local(p.R_W_P.transpose() * (V3(0, 0, 3) - p.t_W_P),
                              p.R_W_P.transpose() * V3(0, 0, -1), &t, &c));
    REQUIRE(t == Approx(2.0).margin(kExact_m));
    REQUIRE(c == Approx(1.0).margin(kExact_m));
    REQUIRE(p.distance_m(V3(5, -3, 1.25)) == Approx(0.25).margin(kExact_m));
  }
  SECTION("box, entering through the -x face") {
    const Primitive p = make_box(V3(1, 0, 0), V3(0.5, 0.25, 0.25));
    REQUIRE(p.intersect_local(V3(-2, 0.1, 0), V3(1, 0, 0), &t, &c));
    REQUIRE(t == Approx(1.5).margin(kExact_m));
    REQUIRE(p.distance_m(V3(1, 0, 1)) == Approx(0.75).margin(kExact_m));
    REQUIRE(p.distance_m(V3(1, 0, 0)) == Approx(-0.25).margin(kExact_m));
    REQUIRE(p.distance_m(V3(2, 1.25, 0)) == Approx(std::sqrt(0.5 * 0.5 + 1.0)).margin(kExact_m));
  }
  SECTION("sphere") {
    const Primitive p = make_sphere(V3(0, 0, 5), 1.0);
    REQUIRE(p.intersect_local(V3(0, 0, -5), V3(0, 0, 1), &t, &c));
    REQUIRE(t == Approx(4.0).margin(kExact_m));
    REQUIRE(p.distance_m(V3(0, 3, 5)) == Approx(2.0).margin(kExact_m));
  }
  SECTION("capsule: side and end cap") {
    const Primitive p = make_capsule(V3(0, 0, -1), V3(0, 0, 1), 0.0025);
    REQUIRE(p.intersect_local(V3(-1, 0, 0.5), V3(1, 0, 0), &t, &c));
    REQUIRE(t == Approx(1.0 - 0.0025).margin(kExact_m));
    REQUIRE(c == Approx(1.0).margin(kExact_m));
    REQUIRE(p.intersect_local(V3(0, 0, 3), V3(0, 0, -1), &t, &c));
    REQUIRE(t == Approx(2.0 - 0.0025).margin(kExact_m));
    REQUIRE(p.distance_m(V3(0, 0, 2)) == Approx(1.0 - 0.0025).margin(kExact_m));
  }
  SECTION("cylinder: side and flat cap") {
    const Primitive p = make_cylinder(V3(0, 0, 0), V3(0, 0, 2), 0.5);
    REQUIRE(p.intersect_local(V3(0.1, 0.2, 4), V3(0, 0, -1), &t, &c));
    REQUIRE(t == Approx(3.0).margin(kExact_m));
    REQUIRE(p.intersect_local(V3(-2, 0, 0.3), V3(1, 0, 0), &t, &c));
    REQUIRE(t == Approx(1.5).margin(kExact_m));
    REQUIRE(p.distance_m(V3(1.5, 0, 3)) == Approx(std::sqrt(2.0)).margin(kExact_m));
  }
  SECTION("rays that miss or start inside see nothing") {
    const Primitive sphere = make_sphere(V3::Zero(), 1.0);
    REQUIRE(!sphere.intersect_local(V3(0, 2, -5), V3(0, 0, 1), &t, &c));
    REQUIRE(!sphere.intersect_local(V3(0, 0, 0), V3(0, 0, 1), &t, &c));
    REQUIRE(!sphere.intersect_local(V3(0, 0, 5), V3(0, 0, 1), &t, &c));  // behind
    const Primitive box = make_box(V3::Zero(), V3(1, 1, 1));
    REQUIRE(!box.intersect_local(V3(0, 0, 0), V3(1, 0, 0), &t, &c));
    REQUIRE(!box.intersect_local(V3(0, 2, -5), V3(0, 0, 1), &t, &c));
  }
}

// Sphere tracing with the primitive's own distance must stop where the analytic intersection
// says: the renderer and the distance query describe one surface.
TEST_CASE("analytic intersection agrees with sphere tracing the distance, every kind") {
  Primitive prims[] = {
      make_box(V3(0.1, -0.2, 0.3), V3(0.3, 0.2, 0.1),
               Eigen::AngleAxisd(0.7, V3(1, 2, 3).normalized()).toRotationMatrix()),
      make_sphere(V3(0.2, 0.1, -0.1), 0.35),
      make_capsule(V3(-0.3, 0.1, 0.0), V3(0.4, -0.2, 0.3), 0.05),
      make_cylinder(V3(-0.2, -0.3, -0.2), V3(0.3, 0.4, 0.2), 0.2),
  };
  SplitMix64 rng(42);
  int hits = 0;
  int misses = 0;
  for (const Primitive& p : prims) {
    for (int i = 0; i < 2000; ++i) {
      // Origin on a 2 m sphere, aimed near the centre.
      const V3 o_P =
          2.0 * V3(rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5).normalized();
      const V3 aim = 0.6 * V3(rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5);
      const V3 d_P = (aim - o_P).normalized();
      double t_hit = 0.0;
      double cos_hit = 0.0;
      const bool hit = p.intersect_local(o_P, d_P, &t_hit, &cos_hit);

      double t = 0.0;
      bool traced = false;
      for (int step = 0; step < 10000 && t < 5.0; ++step) {
        const double d = p.distance_local_m(o_P + t * d_P);
        if (d < 1e-10) {
          traced = true;
          break;
        }
        t += d;
      }
      REQUIRE(hit == traced);
      if (hit) {
        ++hits;
        REQUIRE(t_hit == Approx(t).margin(kTraceAgreement_m));
        REQUIRE(std::abs(p.distance_local_m(o_P + t_hit * d_P)) < kSurface_m);
        REQUIRE(cos_hit >= 0.0);
        REQUIRE(cos_hit <= 1.0);
      } else {
        ++misses;
      }
    }
  }
  REQUIRE(hits > 1000);
  REQUIRE(misses > 1000);
}

TEST_CASE("the scene distance is the union of its primitives") {
  Scene scene;
  REQUIRE(scene.add(make_plane(V3(0, 0, 0), V3(0, 0, 1))).ok());
  REQUIRE(scene.add(make_sphere(V3(0, 0, 1), 0.5), Part::cable).ok());
  REQUIRE(scene.size() == 2);
  REQUIRE(scene[1].part == Part::cable);
  REQUIRE(scene[1].thin());
  REQUIRE(!scene[0].thin());
  REQUIRE(scene.distance_m(V3(0, 0, 2)) == Approx(0.5).margin(kExact_m));
  REQUIRE(scene.distance_m(V3(3, 0, 0.25)) == Approx(0.25).margin(kExact_m));
  REQUIRE(scene.distance_m(V3(0, 0, 1)) == Approx(-0.5).margin(kExact_m));

  double t = 0.0;
  double c = 0.0;
  REQUIRE(scene.intersect(V3(0, 0, 3), V3(0, 0, -1), 10.0, &t, &c) == 1);
  REQUIRE(t == Approx(1.5).margin(kExact_m));
  REQUIRE(scene.intersect(V3(2, 0, 3), V3(0, 0, -1), 10.0, &t, &c) == 0);
  REQUIRE(t == Approx(3.0).margin(kExact_m));
  REQUIRE(scene.intersect(V3(2, 0, 3), V3(0, 0, -1), 2.0, &t, &c) == -1);  // beyond t_max
}

TEST_CASE("add rejects bad primitives and reports a full scene") {
  Scene scene;
  REQUIRE(scene.add(make_sphere(V3::Zero(), 0.0)).code() == StatusCode::invalid_argument);
  REQUIRE(scene.add(make_sphere(V3::Zero(), std::nan(""))).code() == StatusCode::invalid_argument);
  REQUIRE(scene.add(make_box(V3::Zero(), V3(1, -1, 1))).code() == StatusCode::invalid_argument);
  REQUIRE(scene.add(make_capsule(V3::Zero(), V3::Zero(), 0.1)).code() ==
          StatusCode::invalid_argument);
  REQUIRE(scene.add(make_box(V3::Zero(), V3(1, 1, 1), 2.0 * Eigen::Matrix3d::Identity())).code() ==
          StatusCode::invalid_argument);
  REQUIRE(scene.size() == 0);
  for (std::size_t i = 0; i < Scene::kMaxPrimitives; ++i) {
    REQUIRE(scene.add(make_sphere(V3(static_cast<double>(i), 0, 0), 0.1)).ok());
  }
  REQUIRE(scene.add(make_sphere(V3::Zero(), 0.1)).code() == StatusCode::resource_exhausted);
}

TEST_CASE("bounds contain the primitive") {
  const Primitive prims[] = {
      make_box(V3(1, 2, 3), V3(0.3, 0.2, 0.1),
               Eigen::AngleAxisd(0.5, V3(0, 1, 1).normalized()).toRotationMatrix()),
      make_capsule(V3(0, 0, 0), V3(1, 1, 0), 0.1),
      make_cylinder(V3(0, 0, 0), V3(0, 1, 1), 0.2),
      make_sphere(V3(1, 1, 1), 0.5),
  };
  Scene scene;
  for (const Primitive& p : prims) REQUIRE(scene.add(p).ok());
  for (const Primitive& p : scene) {
    std::vector<V3> own(500);
    Scene single;
    REQUIRE(single.add(p).ok());
    const std::size_t n = single.sample_surface(kAllParts, 9, own.data(), own.size());
    REQUIRE(n == own.size());
    for (const V3& q : own) {
      REQUIRE((q.array() >= single[0].aabb_min_W.array() - kSurface_m).all());
      REQUIRE((q.array() <= single[0].aabb_max_W.array() + kSurface_m).all());
    }
  }
}

TEST_CASE("surface samples lie on the surface of the chosen parts, deterministically") {
  Scene scene;
  REQUIRE(scene.add(make_plane(V3(0, 0, 0), V3(0, 0, 1))).ok());
  REQUIRE(scene.add(make_box(V3(0, 0, 0.5), V3(0.5, 0.5, 0.5))).ok());
  // Partly buried in the box: only the part outside is surface.
  REQUIRE(scene.add(make_capsule(V3(0, 0, 1.0), V3(2, 0, 1.0), 0.01), Part::cable).ok());
  std::vector<V3> a(4000);
  std::vector<V3> b(4000);
  const std::size_t n = scene.sample_surface(part_bit(Part::cable), 5, a.data(), a.size());
  REQUIRE(scene.sample_surface(part_bit(Part::cable), 5, b.data(), b.size()) == n);
  REQUIRE(n > a.size() / 2);
  REQUIRE(n < a.size());  // the buried quarter was dropped
  for (std::size_t i = 0; i < n; ++i) {
    REQUIRE(a[i] == b[i]);
    REQUIRE(std::abs(scene.distance_m(a[i])) < kSurface_m);
    REQUIRE(std::abs(scene[2].distance_m(a[i])) < kSurface_m);
  }
  REQUIRE(scene.sample_surface(part_bit(Part::mug_handle), 5, a.data(), a.size()) == 0);
}

}  // namespace
}  // namespace octofuse::sim
