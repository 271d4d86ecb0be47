// Organised point clouds as depth frames: intrinsics estimation, depth image, integration.

#include <cmath>
#include <string>

#include "planesdf/error.hpp"
#include "planesdf/tsdf.hpp"

namespace planesdf {

namespace {

void requireOrganized(const PointCloud& cloud, const char* who) {
  cloud.validate(std::string(who) + ": cloud");
  if (!cloud.isOrganized() || cloud.width == 0)
    throw Error("", std::string(who) + ": the cloud is not organised (height " +
                        std::to_string(cloud.height) + ")");
}

/// 1D least squares y = a * x + b with its RMS residual.
struct LineFit {
  double n = 0, sx = 0, sy = 0;  // first pass: means
  double sxx = 0, sxy = 0;       // second pass: centred sums
  double a = 0, b = 0;
};

}  // namespace

Intrinsics estimateIntrinsics(const PointCloud& organized, double* rms_px) {
  requireOrganized(organized, "estimateIntrinsics");
  const Eigen::Isometry3f T_sensor_cloud =
      organized.sensor_pose.inverse(Eigen::Isometry).cast<float>();
  const std::uint32_t W = organized.width;
  // Normalised coordinates (x/z, y/z) of valid points, with their pixel (u, v).
  const auto normalised = [&](std::size_t i, Eigen::Vector2d* q) {
    const Eigen::Vector3f& p = organized.points[i];
    if (!PointCloud::isValid(p)) return false;
    const Eigen::Vector3f s = T_sensor_cloud * p;
    if (!(s.z() > 0.0f)) return false;
    *q = Eigen::Vector2d(double(s.x()) / s.z(), double(s.y()) / s.z());
    return true;
  };
  LineFit fu, fv;
  Eigen::Vector2d q;
  for (std::size_t i = 0; i < organized.size(); ++i) {
    if (!normalised(i, &q)) continue;
    const double u = double(i % W), v = double(i / W);
    fu.n += 1;
    fu.sx += q.x();
    fu.sy += u;
    fv.sx += q.y();
    fv.sy += v;
  }
  if (fu.n < 3)
    throw Error("", "estimateIntrinsics: fewer than 3 valid points in the organised cloud");
  fv.n = fu.n;
  for (LineFit* f : {&fu, &fv}) {
    f->sx /= f->n;
    f->sy /= f->n;
  }
  for (std::size_t i = 0; i < organized.size(); ++i) {
    if (!normalised(i, &q)) continue;
    const double u = double(i % W) - fu.sy, v = double(i / W) - fv.sy;
    const double x = q.x() - fu.sx, y = q.y() - fv.sx;
    fu.sxx += x * x;
    fu.sxy += x * u;
    fv.sxx += y * y;
    fv.sxy += y * v;
  }
  if (!(fu.sxx > 1e-12 * fu.n) || !(fv.sxx > 1e-12 * fv.n))
    throw Error("", "estimateIntrinsics: the valid points span a single row or column");
  Intrinsics K;
  K.fx = fu.sxy / fu.sxx;
  K.cx = fu.sy - K.fx * fu.sx;
  K.fy = fv.sxy / fv.sxx;
  K.cy = fv.sy - K.fy * fv.sx;
  K.width = static_cast<int>(W);
  K.height = static_cast<int>(organized.height);
  if (!(K.fx > 0.0 && K.fy > 0.0))
    throw Error("",
                "estimateIntrinsics: the fit gives a non-positive focal length; is the "
                "cloud in the sensor's optical frame (z forward)?");
  if (rms_px) {
    double ss = 0.0;
    for (std::size_t i = 0; i < organized.size(); ++i) {
      if (!normalised(i, &q)) continue;
      const double du = K.fx * q.x() + K.cx - double(i % W);
      const double dv = K.fy * q.y() + K.cy - double(i / W);
      ss += du * du + dv * dv;
    }
    *rms_px = std::sqrt(ss / fu.n);
  }
  return K;
}

DepthFrame depthFromOrganizedCloud(const PointCloud& organized, const Intrinsics& intrinsics) {
  requireOrganized(organized, "depthFromOrganizedCloud");
  intrinsics.validate("depthFromOrganizedCloud: intrinsics");
  if (static_cast<std::uint32_t>(intrinsics.width) != organized.width ||
      static_cast<std::uint32_t>(intrinsics.height) != organized.height)
    throw Error("", "depthFromOrganizedCloud: cloud is " + std::to_string(organized.width) + "x" +
                        std::to_string(organized.height) + " but the intrinsics are " +
                        std::to_string(intrinsics.width) + "x" + std::to_string(intrinsics.height));
  const Eigen::Isometry3f T_sensor_cloud =
      organized.sensor_pose.inverse(Eigen::Isometry).cast<float>();
  DepthFrame frame;
  frame.intrinsics = intrinsics;
  frame.depth.assign(organized.size(), 0.0f);
  for (std::size_t i = 0; i < organized.size(); ++i) {
    const Eigen::Vector3f& p = organized.points[i];
    if (!PointCloud::isValid(p)) continue;
    const float z = (T_sensor_cloud * p).z();
    if (z > 0.0f && std::isfinite(z)) frame.depth[i] = z;
  }
  return frame;
}

IntegrationResult integrateOrganizedCloud(TsdfVolume& vol, const PointCloud& organized,
                                          const Pose& T_local_cloud, const Config& cfg,
                                          const Intrinsics* intrinsics) {
  const Intrinsics K = intrinsics ? *intrinsics : estimateIntrinsics(organized);
  const DepthFrame frame = depthFromOrganizedCloud(organized, K);
  return integrateDepth(vol, frame, T_local_cloud * organized.sensor_pose, cfg);
}

}  // namespace planesdf
