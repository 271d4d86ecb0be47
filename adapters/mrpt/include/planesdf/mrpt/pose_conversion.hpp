#pragma once
/// \file pose_conversion.hpp
/// planesdf::Pose <-> mrpt::poses::CPose3D. MRPT types are forward-declared so including this
/// header does not pull MRPT's (slow to compile) headers into the user's translation unit.

#include "planesdf/types.hpp"

namespace mrpt::poses {
class CPose3D;
}

namespace planesdf::mrpt_adapter {

/// The same rigid transform as a planesdf Pose (no change of axes).
Pose toPose(const mrpt::poses::CPose3D& p);
/// The same rigid transform as an MRPT CPose3D (no change of axes).
mrpt::poses::CPose3D toCPose3D(const Pose& pose);

}  // namespace planesdf::mrpt_adapter
