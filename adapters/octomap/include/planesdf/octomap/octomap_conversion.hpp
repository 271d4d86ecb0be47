#pragma once
/// \file octomap_conversion.hpp
/// planesdf clouds and poses as OctoMap types.

#include <octomap/Pointcloud.h>
#include <octomap/math/Pose6D.h>

#include "planesdf/types.hpp"

namespace planesdf::octomap_adapter {

/// The valid (finite) points of `cloud`, transformed by `T` (default identity).
octomap::Pointcloud toOctomap(const PointCloud& cloud, const Pose& T = Pose::Identity());
/// A rigid transform as octomap::pose6d.
octomath::Pose6D toOctomap(const Pose& pose);

}  // namespace planesdf::octomap_adapter
