#include "planesdf/octomap/octomap_conversion.hpp"

#include <Eigen/Geometry>

namespace planesdf::octomap_adapter {

octomap::Pointcloud toOctomap(const PointCloud& cloud, const Pose& T) {
  octomap::Pointcloud out;
  out.reserve(cloud.size());
  const Eigen::Matrix3f R = T.linear().cast<float>();
  const Eigen::Vector3f t = T.translation().cast<float>();
  for (const auto& p : cloud.points) {
    if (!PointCloud::isValid(p)) continue;
    const Eigen::Vector3f q = R * p + t;
    out.push_back(q.x(), q.y(), q.z());
  }
  return out;
}

octomath::Pose6D toOctomap(const Pose& pose) {
  const Eigen::Quaterniond q(pose.linear());
  const Eigen::Vector3d t = pose.translation();
  return octomath::Pose6D(
      octomath::Vector3(static_cast<float>(t.x()), static_cast<float>(t.y()),
                        static_cast<float>(t.z())),
      octomath::Quaternion(static_cast<float>(q.w()), static_cast<float>(q.x()),
                           static_cast<float>(q.y()), static_cast<float>(q.z())));
}

}  // namespace planesdf::octomap_adapter
