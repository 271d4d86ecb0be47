#include "planesdf/mrpt/pose_conversion.hpp"

#include <mrpt/math/CMatrixFixed.h>
#include <mrpt/poses/CPose3D.h>

namespace planesdf::mrpt_adapter {

Pose toPose(const mrpt::poses::CPose3D& p) {
  const auto m = p.getHomogeneousMatrixVal<mrpt::math::CMatrixDouble44>();
  Pose out = Pose::Identity();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) out.matrix()(r, c) = m(r, c);
  return out;
}

mrpt::poses::CPose3D toCPose3D(const Pose& pose) {
  mrpt::math::CMatrixDouble44 m;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) m(r, c) = pose.matrix()(r, c);
  return mrpt::poses::CPose3D(m);
}

}  // namespace planesdf::mrpt_adapter
