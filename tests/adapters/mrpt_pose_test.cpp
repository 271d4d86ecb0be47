// The MRPT adapter's pose conversion against poses built independently on both sides.
#include <gtest/gtest.h>
#include <mrpt/poses/CPose3D.h>

#include <cmath>

#include "planesdf/mrpt/pose_conversion.hpp"

namespace {
using planesdf::Pose;
namespace ma = planesdf::mrpt_adapter;

TEST(MrptPose, YawPitchRollMatchesEigen) {
  const double yaw = 0.3, pitch = -0.2, roll = 0.7;
  const mrpt::poses::CPose3D p(1.0, -2.0, 0.5, yaw, pitch, roll);
  // MRPT's convention: R = Rz(yaw) * Ry(pitch) * Rx(roll).
  Pose expected = Pose::Identity();
  expected.linear() = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                       Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
                       Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
                          .toRotationMatrix();
  expected.translation() = Eigen::Vector3d(1.0, -2.0, 0.5);
  const Pose got = ma::toPose(p);
  EXPECT_LT((got.matrix() - expected.matrix()).cwiseAbs().maxCoeff(), 1e-12);
}

TEST(MrptPose, RoundTripAndPointTransform) {
  Pose pose = Pose::Identity();
  pose.linear() = Eigen::AngleAxisd(1.1, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  pose.translation() = Eigen::Vector3d(0.4, 0.5, -0.6);
  const mrpt::poses::CPose3D p = ma::toCPose3D(pose);
  const Eigen::Vector3d x(0.3, -1.2, 2.0);
  mrpt::math::TPoint3D gx;
  p.composePoint(mrpt::math::TPoint3D(x.x(), x.y(), x.z()), gx);
  const Eigen::Vector3d ex = pose * x;
  EXPECT_NEAR(gx.x, ex.x(), 1e-12);
  EXPECT_NEAR(gx.y, ex.y(), 1e-12);
  EXPECT_NEAR(gx.z, ex.z(), 1e-12);
  EXPECT_LT((ma::toPose(p).matrix() - pose.matrix()).cwiseAbs().maxCoeff(), 1e-12);
}

}  // namespace
