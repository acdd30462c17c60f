#pragma once
// Rigid transforms. Naming: T_A_B maps points from frame B to frame A (p_A = T_A_B * p_B);
// W = world, C = camera (optical: x right, y down, z forward). Poses are kept in double (they
// accumulate over thousands of frames); hot loops take a float copy per frame.

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace octofuse {

using Se3d = Eigen::Isometry3d;
using Se3f = Eigen::Isometry3f;
using Vector6d = Eigen::Matrix<double, 6, 1>;

// True when the top-left 3x3 of `T` is a rotation (orthonormal, det +1) within `tolerance`, the
// bottom row is (0 0 0 1) and every entry is finite.
bool is_rigid(const Eigen::Matrix4d& T, double tolerance = 1e-4);

// Exponential map: twist (v, w) = (translation part, rotation vector) to a rigid transform.
// Uses the closed form with a series fallback near zero rotation.
Se3d se3_exp(const Vector6d& twist);

// Inverse of se3_exp for rotations below pi.
Vector6d se3_log(const Se3d& T);

// Nearest rotation (SVD projection); fixes drift after many compositions.
Eigen::Matrix3d orthonormalize(const Eigen::Matrix3d& R);

}  // namespace octofuse
