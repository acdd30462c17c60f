#include "octofuse/math/se3.hpp"

#include <cmath>

#include <Eigen/SVD>

namespace octofuse {

bool is_rigid(const Eigen::Matrix4d& T, double tolerance) {
  if (!T.allFinite()) return false;
  if (std::abs(T(3, 0)) > tolerance || std::abs(T(3, 1)) > tolerance ||
      std::abs(T(3, 2)) > tolerance || std::abs(T(3, 3) - 1.0) > tolerance) {
    return false;
  }
  const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
  const Eigen::Matrix3d residual = R.transpose() * R - Eigen::Matrix3d::Identity();
  if (residual.cwiseAbs().maxCoeff() > tolerance) return false;
  return std::abs(R.determinant() - 1.0) <= tolerance;
}

namespace {
Eigen::Matrix3d skew(const Eigen::Vector3d& w) {
  Eigen::Matrix3d S;
  S << 0.0, -w.z(), w.y(), w.z(), 0.0, -w.x(), -w.y(), w.x(), 0.0;
  return S;
}
}  // namespace

Se3d se3_exp(const Vector6d& twist) {
  const Eigen::Vector3d v = twist.head<3>();
  const Eigen::Vector3d w = twist.tail<3>();
  const double theta = w.norm();
  const Eigen::Matrix3d W = skew(w);
  double a, b, c;  // R = I + a W + b W^2; V = I + b W + c W^2
  if (theta < 1e-8) {
    a = 1.0;
    b = 0.5;
    c = 1.0 / 6.0;
  } else {
    const double t2 = theta * theta;
    a = std::sin(theta) / theta;
    b = (1.0 - std::cos(theta)) / t2;
    c = (theta - std::sin(theta)) / (t2 * theta);
  }
  const Eigen::Matrix3d I = Eigen::Matrix3d::Identity();
  Se3d T = Se3d::Identity();
  T.linear() = I + a * W + b * W * W;
  T.translation() = (I + b * W + c * W * W) * v;
  return T;
}

Vector6d se3_log(const Se3d& T) {
  const Eigen::AngleAxisd aa(Eigen::Matrix3d(T.linear()));
  const Eigen::Vector3d w = aa.axis() * aa.angle();
  const double theta = aa.angle();
  const Eigen::Matrix3d W = skew(w);
  const Eigen::Matrix3d I = Eigen::Matrix3d::Identity();
  Eigen::Matrix3d V_inv;
  if (theta < 1e-8) {
    V_inv = I - 0.5 * W + (1.0 / 12.0) * W * W;
  } else {
    const double half = 0.5 * theta;
    const double k = (1.0 - half * std::cos(half) / std::sin(half)) / (theta * theta);
    V_inv = I - 0.5 * W + k * W * W;
  }
  Vector6d twist;
  twist.head<3>() = V_inv * T.translation();
  twist.tail<3>() = w;
  return twist;
}

Eigen::Matrix3d orthonormalize(const Eigen::Matrix3d& R) {
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(R, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d U = svd.matrixU();
  const Eigen::Matrix3d V = svd.matrixV();
  if ((U * V.transpose()).determinant() < 0.0) U.col(2) = -U.col(2);
  return U * V.transpose();
}

}  // namespace octofuse
