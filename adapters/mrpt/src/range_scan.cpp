#include "planesdf/mrpt/range_scan.hpp"

#include <mrpt/io/CFileGZInputStream.h>
#include <mrpt/obs/CObservation3DRangeScan.h>
#include <mrpt/obs/CObservationOdometry.h>
#include <mrpt/obs/CObservationRobotPose.h>
#include <mrpt/obs/CSensoryFrame.h>
#include <mrpt/poses/CPose3D.h>
#include <mrpt/serialization/CArchive.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>

#include "planesdf/error.hpp"
#include "planesdf/mrpt/pose_conversion.hpp"

namespace planesdf::mrpt_adapter {

Pose opticalToMrptSensor() {
  Pose R = Pose::Identity();
  R.linear() << 0, 0, 1,  //
      -1, 0, 0,           //
      0, -1, 0;
  return R;
}

DepthFrame toDepthFrame(const mrpt::obs::CObservation3DRangeScan& scan, const std::string& what) {
  scan.load();
  if (!scan.hasRangeImage) throw Error(what, "the 3D range scan has no range image");
  const auto& cam = scan.cameraParams;
  DepthFrame f;
  f.intrinsics.fx = cam.fx();
  f.intrinsics.fy = cam.fy();
  f.intrinsics.cx = cam.cx();
  f.intrinsics.cy = cam.cy();
  f.intrinsics.width = static_cast<int>(cam.ncols);
  f.intrinsics.height = static_cast<int>(cam.nrows);
  f.intrinsics.validate(what + ": cameraParams");
  const int w = f.intrinsics.width, h = f.intrinsics.height;
  if (scan.rangeImage.cols() != w || scan.rangeImage.rows() != h)
    throw Error(what, "range image is " + std::to_string(scan.rangeImage.cols()) + "x" +
                          std::to_string(scan.rangeImage.rows()) + " but cameraParams say " +
                          std::to_string(w) + "x" + std::to_string(h));
  f.timestamp = mrpt::Clock::toDouble(scan.timestamp);
  f.depth.assign(static_cast<std::size_t>(w) * h, 0.0f);
  const float units = scan.rangeUnits;
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) {
      const std::uint16_t raw = scan.rangeImage(r, c);
      if (raw == 0) continue;
      double d = raw * static_cast<double>(units);
      if (!scan.range_is_depth) {  // a distance along the ray: project on the optical axis
        const double ky = (f.intrinsics.cx - c) / f.intrinsics.fx;
        const double kz = (f.intrinsics.cy - r) / f.intrinsics.fy;
        d /= std::sqrt(1.0 + ky * ky + kz * kz);
      }
      f.depth[static_cast<std::size_t>(r) * w + c] = static_cast<float>(d);
    }
  return f;
}

Pose cameraPose(const mrpt::obs::CObservation3DRangeScan& scan, const Pose& robot_pose) {
  return robot_pose * toPose(scan.sensorPose) * opticalToMrptSensor();
}

void toRangeScan(const DepthFrame& frame, const Pose& camera_to_world,
                 mrpt::obs::CObservation3DRangeScan& scan, float range_units) {
  const Intrinsics& k = frame.intrinsics;
  k.validate("depth frame");
  if (frame.depth.size() != static_cast<std::size_t>(k.width) * k.height)
    throw Error("depth frame", "depth buffer size disagrees with the intrinsics");
  if (!(range_units > 0.0f)) throw Error("depth frame", "range_units must be positive");
  scan.hasRangeImage = true;
  scan.range_is_depth = true;
  scan.rangeUnits = range_units;
  scan.rangeImage_setSize(k.height, k.width);
  for (int r = 0; r < k.height; ++r)
    for (int c = 0; c < k.width; ++c) {
      const float d = frame.at(c, r);
      const double q = DepthFrame::isValidDepth(d) ? std::round(d / range_units) : 0.0;
      scan.rangeImage(r, c) = static_cast<std::uint16_t>(q > 65535.0 ? 0.0 : q);
    }
  scan.cameraParams.ncols = static_cast<std::uint32_t>(k.width);
  scan.cameraParams.nrows = static_cast<std::uint32_t>(k.height);
  scan.cameraParams.setIntrinsicParamsFromValues(k.fx, k.fy, k.cx, k.cy);
  scan.cameraParamsIntensity = scan.cameraParams;
  scan.sensorPose = toCPose3D(camera_to_world * opticalToMrptSensor().inverse());
  scan.timestamp = mrpt::Clock::fromDouble(frame.timestamp);
}

namespace {

/// The first line of an MRPT exception message (the rest is a backtrace).
std::string firstLine(const std::string& text) {
  std::string line = text.substr(0, text.find('\n'));
  while (!line.empty() && std::isspace(static_cast<unsigned char>(line.back()))) line.pop_back();
  return line;
}

}  // namespace

std::size_t readRawlog(const std::string& path,
                       const std::function<void(const RawlogScan&)>& on_scan) {
  if (!std::filesystem::is_regular_file(path)) throw Error(path, "no such rawlog file");
  mrpt::io::CFileGZInputStream file;
  bool opened = false;
  try {
    opened = file.open(path);
  } catch (const std::exception& e) {
    throw Error(path, "cannot open: " + firstLine(e.what()));
  }
  if (!opened) throw Error(path, "cannot open");
  auto archive = mrpt::serialization::archiveFrom(file);

  Pose robot = Pose::Identity();
  std::size_t scans = 0, objects = 0;
  const auto handle = [&](const mrpt::obs::CObservation::Ptr& obs) {
    if (!obs) return;
    if (const auto* rp = dynamic_cast<const mrpt::obs::CObservationRobotPose*>(obs.get())) {
      robot = toPose(mrpt::poses::CPose3D(rp->pose.mean));
    } else if (const auto* od = dynamic_cast<const mrpt::obs::CObservationOdometry*>(obs.get())) {
      robot = toPose(mrpt::poses::CPose3D(od->odometry));
    } else if (const auto* s = dynamic_cast<const mrpt::obs::CObservation3DRangeScan*>(obs.get())) {
      s->load();
      if (!s->hasRangeImage) return;
      RawlogScan out;
      const std::string what = path + ": object " + std::to_string(objects);
      out.frame = toDepthFrame(*s, what);
      out.pose = cameraPose(*s, robot);
      out.sensor_label = s->sensorLabel;
      ++scans;
      on_scan(out);
    }
  };
  for (;;) {
    mrpt::serialization::CSerializable::Ptr obj;
    try {
      archive >> obj;
    } catch (const mrpt::serialization::CExceptionEOF&) {
      break;
    } catch (const Error&) {
      throw;
    } catch (const std::exception& e) {
      throw Error(path, "object " + std::to_string(objects) +
                            ": cannot read (truncated or not a rawlog?): " + firstLine(e.what()));
    }
    if (const auto sf = std::dynamic_pointer_cast<mrpt::obs::CSensoryFrame>(obj)) {
      for (const auto& o : *sf) handle(o);
    } else if (const auto o = std::dynamic_pointer_cast<mrpt::obs::CObservation>(obj)) {
      handle(o);
    }  // CActionCollection and anything else: skipped
    ++objects;
  }
  if (scans == 0)
    throw Error(path, "no CObservation3DRangeScan with a range image in " +
                          std::to_string(objects) + " objects");
  return scans;
}

std::vector<RawlogScan> loadRawlog(const std::string& path) {
  std::vector<RawlogScan> out;
  readRawlog(path, [&](const RawlogScan& s) { out.push_back(s); });
  return out;
}

}  // namespace planesdf::mrpt_adapter
