#include "session_input.hpp"

#include <algorithm>
#include <cctype>
#include <chrono>
#include <filesystem>
#include <iostream>
#include <sstream>
#include <vector>

#include "planesdf/error.hpp"
#include "planesdf/io/cloud.hpp"
#include "planesdf/io/tum.hpp"
#include "planesdf/memory.hpp"
#ifdef PLANESDF_HAVE_MRPT
#include "planesdf/mrpt/range_scan.hpp"
#endif

namespace planesdf::cli {
namespace fs = std::filesystem;

Intrinsics parseIntrinsics(const std::string& text) {
  std::vector<double> v;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    try {
      std::size_t used = 0;
      v.push_back(std::stod(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw Error("--intrinsics", "'" + item + "' is not a number (expected fx,fy,cx,cy[,w,h])");
    }
  }
  if (v.size() != 4 && v.size() != 6)
    throw Error("--intrinsics",
                "expected fx,fy,cx,cy or fx,fy,cx,cy,width,height, got '" + text + "'");
  Intrinsics k;
  k.fx = v[0];
  k.fy = v[1];
  k.cx = v[2];
  k.cy = v[3];
  if (v.size() == 6) {
    if (v[4] != std::floor(v[4]) || v[5] != std::floor(v[5]) || v[4] < 1 || v[5] < 1 ||
        v[4] > 16384 || v[5] > 16384)
      throw Error("--intrinsics", "width and height must be whole numbers in [1, 16384]");
    k.width = static_cast<int>(v[4]);
    k.height = static_cast<int>(v[5]);
  }
  k.validate("--intrinsics");
  return k;
}

#ifndef PLANESDF_HAVE_MRPT
[[noreturn]] void throwWithoutMrpt(const std::string& path) {
  throw Error(path,
              ".rawlog input needs the MRPT adapter: this planesdf was built without it "
              "(configure with -DPLANESDF_BUILD_MRPT=ON and libmrpt-dev installed)");
}
#endif

std::string lowerExtension(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext;
}

void printRawlogInfo(const std::string& path) {
#ifdef PLANESDF_HAVE_MRPT
  std::size_t n = 0;
  Intrinsics k;
  Eigen::AlignedBox3d trajectory;
  mrpt_adapter::readRawlog(path, [&](const mrpt_adapter::RawlogScan& scan) {
    if (n++ == 0) k = scan.frame.intrinsics;
    trajectory.extend(scan.pose.translation());
  });
  std::cout << "MRPT rawlog " << path << "\n"
            << "  3D range scans: " << n << "\n";
  if (n == 0) return;
  const Eigen::Vector3d size = trajectory.sizes();
  std::cout << "  first scan:     " << k.width << "x" << k.height << ", fx=" << k.fx
            << " fy=" << k.fy << " cx=" << k.cx << " cy=" << k.cy << "\n"
            << "  trajectory:     " << size.x() << " x " << size.y() << " x " << size.z() << " m\n";
#else
  throwWithoutMrpt(path);
#endif
}

namespace {

Map fuseTum(const std::string& folder, const Config& cfg, const std::string& intrinsics,
            const std::string& label) {
  io::TumOptions opt;
  if (!intrinsics.empty()) opt.intrinsics = parseIntrinsics(intrinsics);
  const io::TumSequence seq = io::readTumSequence(folder, opt);
  const Intrinsics& k = seq.intrinsics;
  requireMemory(static_cast<std::size_t>(k.width) * k.height * kDepthFrameBytesPerPixel, cfg,
                folder,
                "loading and fusing " + std::to_string(k.width) + "x" + std::to_string(k.height) +
                    " depth frames");
  Map map(cfg);
  const std::size_t n = seq.frames.size();
  auto last = std::chrono::steady_clock::now();
  double total_ms = 0.0;
  std::vector<double> frame_ms;
  for (std::size_t i = 0; i < n; ++i) {
    const IntegrateStats s = map.integrate(io::loadTumDepth(seq, i), seq.frames[i].pose);
    total_ms += s.milliseconds;
    frame_ms.push_back(s.milliseconds);
    const auto now = std::chrono::steady_clock::now();
    if (i + 1 == n || now - last > std::chrono::milliseconds(500)) {
      std::cerr << label << ": frame " << (i + 1) << "/" << n << ", " << map.planes().size()
                << " planes, " << (total_ms / static_cast<double>(i + 1)) << " ms/frame\n";
      last = now;
    }
  }
  if (!frame_ms.empty()) {  // what bench/open3d_peer.py compares (loading a frame not included)
    std::nth_element(frame_ms.begin(), frame_ms.begin() + frame_ms.size() / 2, frame_ms.end());
    std::cerr << label << ": Map::integrate median " << frame_ms[frame_ms.size() / 2]
              << " ms/frame\n";
  }
  if (seq.dropped_frames > 0)
    std::cerr << label << ": " << seq.dropped_frames
              << " depth frames had no ground-truth pose and were skipped\n";
  return map;
}

/// A .rawlog of 3D range scans, fused frame by frame (MRPT adapter builds only).
Map fuseRawlog(const std::string& path, const Config& cfg, const std::string& label) {
#ifdef PLANESDF_HAVE_MRPT
  Map map(cfg);
  auto last = std::chrono::steady_clock::now();
  double total_ms = 0.0;
  std::size_t n = 0;
  mrpt_adapter::readRawlog(path, [&](const mrpt_adapter::RawlogScan& scan) {
    total_ms += map.integrate(scan.frame, scan.pose).milliseconds;
    ++n;
    const auto now = std::chrono::steady_clock::now();
    if (now - last > std::chrono::milliseconds(500)) {
      std::cerr << label << ": scan " << n << ", " << map.planes().size() << " planes, "
                << (total_ms / static_cast<double>(n)) << " ms/frame\n";
      last = now;
    }
  });
  std::cerr << label << ": " << n << " scans, " << map.planes().size() << " planes, "
            << (total_ms / static_cast<double>(n)) << " ms/frame\n";
  return map;
#else
  (void)cfg;
  (void)label;
  throwWithoutMrpt(path);
#endif
}

}  // namespace

namespace {

/// A cloud wider than this (m) with no plane found was most likely given in millimetres.
constexpr double kMillimetreHintExtent = 100.0;

/// Largest side (m) of the bounding box of the cloud's valid points.
double extentOf(const PointCloud& cloud) {
  Eigen::AlignedBox3f box;
  for (std::size_t i = 0; i < cloud.points.size(); ++i)
    if (cloud.isValid(i)) box.extend(cloud.points[i]);
  return box.isEmpty() ? 0.0 : static_cast<double>(box.sizes().maxCoeff());
}

/// Map::fromCloud, with a hint about units when no plane is found in a cloud hundreds of m wide.
Map mapFromCloud(const std::string& input, const PointCloud& cloud, const Config& cfg) {
  Map map = Map::fromCloud(cloud, cfg);
  const double extent = map.planes().empty() ? extentOf(cloud) : 0.0;
  if (extent > kMillimetreHintExtent)
    throw Error(input, "no horizontal or vertical plane found in a cloud " +
                           std::to_string(static_cast<long long>(extent)) +
                           " m wide: if its coordinates are millimetres, scale them to metres");
  return map;
}

Map loadSessionUnnamed(const std::string& input, const Config& cfg, const std::string& intrinsics,
                       const std::string& label, bool up_defaulted) {
  if (fs::is_directory(input)) {
    if (!io::isTumFolder(input))
      throw Error(input, "not a TUM RGB-D sequence (no depth.txt) and not a cloud or map file");
    return fuseTum(input, cfg, intrinsics, label);
  }
  if (lowerExtension(input) == ".psdf") return Map::load(input);
  if (lowerExtension(input) == ".rawlog") return fuseRawlog(input, cfg, label);
  const PointCloud cloud = io::readSceneCloud(input);
  if (up_defaulted && !cfg.up_auto && cloud.isOrganized() &&
      cloud.sensor_pose.isApprox(Pose::Identity())) {
    Config auto_cfg = cfg;
    auto_cfg.up_auto = true;
    std::cerr << label << ": " << input
              << " is an organised cloud in its camera frame: up axis estimated (--up auto)\n";
    return mapFromCloud(input, cloud, auto_cfg);
  }
  return mapFromCloud(input, cloud, cfg);
}

}  // namespace

Map loadSession(const std::string& input, const Config& cfg, const std::string& intrinsics,
                const std::string& label, bool up_defaulted) {
  return namingInput(
      input, [&] { return loadSessionUnnamed(input, cfg, intrinsics, label, up_defaulted); });
}

}  // namespace planesdf::cli
