#pragma once
/// \file range_scan.hpp
/// mrpt::obs::CObservation3DRangeScan <-> planesdf DepthFrame, and reading `.rawlog` files of
/// 3D range scans. MRPT types are forward-declared (see pose_conversion.hpp).
///
/// Axes. MRPT's sensor frame has x forward (the depth axis), y left and z up: pixel (c, r) with
/// depth x sits at (x, (cx - c) x / fx, (cy - r) x / fy). planesdf cameras use the OpenCV
/// optical frame (x right, y down, z forward). So the camera-to-world pose planesdf needs is
/// robot_pose * scan.sensorPose * kOpticalToMrptSensor.

#include <cstddef>
#include <functional>
#include <string>
#include <vector>

#include "planesdf/types.hpp"

namespace mrpt::obs {
class CObservation3DRangeScan;
}

namespace planesdf::mrpt_adapter {

/// The rotation taking OpenCV optical coordinates to MRPT sensor coordinates:
/// (x_mrpt, y_mrpt, z_mrpt) = (z_opt, -x_opt, -y_opt).
Pose opticalToMrptSensor();

/// The scan's depth image in metres (rangeUnits applied; ranges converted to depth along the
/// optical axis when range_is_depth is false) with the intrinsics of scan.cameraParams and the
/// scan's timestamp (seconds, MRPT clock). Loads externally stored images first. Throws
/// planesdf::Error naming `what` when the scan has no range image or its size disagrees with
/// the camera parameters.
DepthFrame toDepthFrame(const mrpt::obs::CObservation3DRangeScan& scan,
                        const std::string& what = "3D range scan");

/// Camera-to-world pose (OpenCV optical frame) of the scan taken with the robot at `robot_pose`:
/// robot_pose * scan.sensorPose * opticalToMrptSensor().
Pose cameraPose(const mrpt::obs::CObservation3DRangeScan& scan,
                const Pose& robot_pose = Pose::Identity());

/// The inverse of toDepthFrame + cameraPose with the robot at the origin: a scan with
/// range_is_depth, rangeUnits = `range_units` (depth rounded to it, 0 = no return),
/// cameraParams from the intrinsics and sensorPose = camera_to_world * opticalToMrptSensor()^-1.
void toRangeScan(const DepthFrame& frame, const Pose& camera_to_world,
                 mrpt::obs::CObservation3DRangeScan& scan, float range_units = 0.001f);

/// One 3D range scan of a rawlog, converted.
struct RawlogScan {
  DepthFrame frame;
  Pose pose = Pose::Identity();  ///< camera-to-world (OpenCV optical frame)
  std::string sensor_label;
};

/// Reads a `.rawlog` file (gzip-compressed or plain, either rawlog format: observations only,
/// or CSensoryFrame / CActionCollection pairs) and calls `on_scan` for each
/// CObservation3DRangeScan with a range image, in file order. The robot pose of a scan is the
/// latest CObservationRobotPose (its mean) or CObservationOdometry seen before it in the file
/// (identity when none), so a rawlog whose scans carry their full pose in sensorPose needs
/// neither. Other observations are skipped, and so are CActionCollection entries: incremental
/// odometry actions are not integrated into a robot pose. Returns the number of scans. Throws
/// planesdf::Error naming the file when it cannot be opened, an object cannot be read (truncated or
/// foreign file), or it holds no 3D range scan with a range image.
std::size_t readRawlog(const std::string& path,
                       const std::function<void(const RawlogScan&)>& on_scan);

/// Every scan of readRawlog in memory.
std::vector<RawlogScan> loadRawlog(const std::string& path);

}  // namespace planesdf::mrpt_adapter
