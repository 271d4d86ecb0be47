// A whole simulation: both sessions rendered (frames in parallel), the whole-scene clouds
// (centroid per kVoxel cell), the ground-truth labels, and the `planesdf simulate` folder.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <set>
#include <string>
#include <system_error>
#include <vector>

#include "../parallel.hpp"
#include "key_index.hpp"
#include "planesdf/error.hpp"
#include "planesdf/io/ply.hpp"
#include "planesdf/io/tum.hpp"
#include "planesdf/sim.hpp"
#include "reconstruct.hpp"
#include "world.hpp"

namespace planesdf::sim {
namespace {
namespace fs = std::filesystem;
using detail::KeyIndex;
using Eigen::Vector3d;

/// A cell is part of a noise shell when a face neighbour holds this many times its points.
constexpr double kShellRatio = 1.5;
/// Points measured at most this deep go into kVoxel cells; each doubling of the depth beyond it
/// doubles the cell (a sensor pixel is 3.8 mm wide at 2 m, 7.6 mm at 4 m).
constexpr double kFineRange = 1.5;
constexpr int kLevels = 4;

// ---- cells --------------------------------------------------------------------------------------

constexpr int kAxisBits = 20;
constexpr std::int64_t kAxisOffset = std::int64_t{1} << (kAxisBits - 1);  // +-1.8 km at 3.5 mm
constexpr std::uint64_t kAxisMask = (std::uint64_t{1} << kAxisBits) - 1;

struct Cell {
  int level = 0;
  std::int64_t x = 0, y = 0, z = 0;
};

std::uint64_t packCell(const Cell& c) {
  const auto axis = [](std::int64_t v) {
    return static_cast<std::uint64_t>(
        std::clamp<std::int64_t>(v + kAxisOffset, 1, static_cast<std::int64_t>(kAxisMask) - 1));
  };
  return (static_cast<std::uint64_t>(c.level) << (3 * kAxisBits)) | (axis(c.x) << (2 * kAxisBits)) |
         (axis(c.y) << kAxisBits) | axis(c.z);
}

Cell unpackCell(std::uint64_t key) {
  const auto axis = [](std::uint64_t v) {
    return static_cast<std::int64_t>(v & kAxisMask) - kAxisOffset;
  };
  return {static_cast<int>(key >> (3 * kAxisBits)), axis(key >> (2 * kAxisBits)),
          axis(key >> kAxisBits), axis(key)};
}

std::int64_t floorDiv(std::int64_t a, std::int64_t b) {
  const std::int64_t q = a / b;
  return (a % b != 0 && a < 0) ? q - 1 : q;
}

/// The cell of world point `p` measured at depth `depth`.
Cell cellOf(const Vector3d& p, double depth) {
  int level = 0;
  for (double range = kFineRange; depth > range && level + 1 < kLevels; range *= 2.0) ++level;
  // The grid is shifted by half a fine cell, so that the fine cells are centred on round
  // coordinates (the floor z = 0) instead of having a cell boundary there (a noisy surface on a
  // boundary splits into two layers of centroids, each off by about the noise).
  const double size = kVoxel * static_cast<double>(1 << level);
  const Vector3d q = (p.array() + 0.5 * kVoxel) / size;
  return {level, static_cast<std::int64_t>(std::floor(q.x())),
          static_cast<std::int64_t>(std::floor(q.y())),
          static_cast<std::int64_t>(std::floor(q.z()))};
}

/// The sum and count of the points of each cell.
class CellAccumulator {
 public:
  explicit CellAccumulator(std::size_t expected) : index_(expected) {}

  void add(std::uint64_t key, const Vector3d& sum, std::uint32_t count) {
    const std::uint32_t i = index_.insert(key);
    if (i == keys_.size()) {
      keys_.push_back(key);
      sums_.push_back(Vector3d::Zero());
      counts_.push_back(0);
    }
    sums_[i] += sum;
    counts_[i] += count;
  }

  /// Adds all cells of `other` (in its insertion order, so the sums are reproducible).
  void merge(const CellAccumulator& other) {
    for (std::size_t i = 0; i < other.keys_.size(); ++i)
      add(other.keys_[i], other.sums_[i], other.counts_[i]);
  }

  /// The centroids, ordered by cell key, of the cells that remain after
  ///  - dropping a cell when a cell of a finer level lies inside it (the surface was seen closer),
  ///  - dropping a cell of a noise shell: a face neighbour of its level holds more than
  ///    kShellRatio times its points (noise spreads a surface over a few cells across it; the
  ///    densest carry the surface).
  std::vector<Vector3d> centroids(int threads) const {
    KeyIndex covered(keys_.size());
    for (const std::uint64_t key : keys_) {
      const Cell c = unpackCell(key);
      for (int level = c.level + 1; level < kLevels; ++level) {
        const std::int64_t f = std::int64_t{1} << (level - c.level);
        const std::size_t before = covered.size();
        covered.insert(packCell({level, floorDiv(c.x, f), floorDiv(c.y, f), floorDiv(c.z, f)}));
        if (covered.size() == before) break;  // already there, and so are its ancestors
      }
    }
    const auto count = [&](std::uint64_t key) {
      const std::uint32_t i = index_.find(key);
      return i == KeyIndex::kNone ? 0u : counts_[i];
    };
    constexpr std::uint64_t kSteps[3] = {std::uint64_t{1} << (2 * kAxisBits),
                                         std::uint64_t{1} << kAxisBits, 1};
    std::vector<std::uint8_t> keep(keys_.size(), 0);
    const std::int64_t n = static_cast<std::int64_t>(keys_.size());
    planesdf::detail::parallelChunks(
        n, threads, planesdf::detail::kPointGrain, [&](int, long long begin, long long end) {
          for (long long j = begin; j < end; ++j) {
            const auto i = static_cast<std::size_t>(j);
            if (covered.find(keys_[i]) != KeyIndex::kNone) continue;
            const double limit = kShellRatio * counts_[i];
            bool shell = false;
            for (const std::uint64_t step : kSteps)
              shell = shell || count(keys_[i] + step) > limit || count(keys_[i] - step) > limit;
            keep[i] = shell ? 0 : 1;
          }
        });
    std::vector<std::uint32_t> kept;
    for (std::size_t i = 0; i < keys_.size(); ++i)
      if (keep[i]) kept.push_back(static_cast<std::uint32_t>(i));
    std::sort(kept.begin(), kept.end(),
              [&](std::uint32_t a, std::uint32_t b) { return keys_[a] < keys_[b]; });
    std::vector<Vector3d> out;
    out.reserve(kept.size());
    for (const std::uint32_t i : kept) out.push_back(sums_[i] / counts_[i]);
    return out;
  }

 private:
  KeyIndex index_;
  std::vector<std::uint64_t> keys_;
  std::vector<Vector3d> sums_;
  std::vector<std::uint32_t> counts_;
};

double secondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

std::string fixed(double v, int decimals) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

/// The centroids of the whole-scene cloud (true frame): every valid pixel of every frame placed
/// with its true pose, one centroid per cell (see CellAccumulator).
std::vector<Vector3d> wholeCloud(const SessionData& data, const Intrinsics& K, int threads) {
  const int n = static_cast<int>(data.frames.size());
  // Frames are binned in parallel, a batch of `threads` frames at a time, and merged in frame
  // order, so the sums (and the output) do not depend on the thread count.
  CellAccumulator cells(static_cast<std::size_t>(n) * 20000);
  for (int batch = 0; batch < n; batch += threads) {
    const int count = std::min(threads, n - batch);
    std::vector<CellAccumulator> partial(
        static_cast<std::size_t>(count),
        CellAccumulator(static_cast<std::size_t>(K.width) * K.height / 2));
    planesdf::detail::parallelFor(count, threads, [&](int k) {
      const DepthFrame& f = data.frames[static_cast<std::size_t>(batch + k)];
      const Pose& T = data.true_poses[static_cast<std::size_t>(batch + k)];
      CellAccumulator& acc = partial[static_cast<std::size_t>(k)];
      for (int v = 0; v < K.height; ++v)
        for (int u = 0; u < K.width; ++u) {
          const float z = f.at(u, v);
          if (!DepthFrame::isValidDepth(z)) continue;
          const Vector3d pc((u - K.cx) / K.fx * z, (v - K.cy) / K.fy * z, z);
          const Vector3d pw = T * pc;
          acc.add(packCell(cellOf(pw, z)), pw, 1);
        }
    });
    for (const CellAccumulator& acc : partial) cells.merge(acc);
  }
  return cells.centroids(threads);
}

/// What the ground truth of one session is measured against: the session's surfaces, those of its
/// changed objects and their ids.
struct Labeller {
  const detail::World& world;
  const detail::World& changed_world;
  const std::set<int>& ids;

  /// The owner of each point (true frame) when it is a changed object (its surface is within
  /// kLabelDistance and nearer than any other surface of the scene), else 0. Only points that near
  /// a changed object need the whole scene.
  std::vector<int> owners(const std::vector<Vector3d>& points, int threads) const {
    const std::int64_t m = static_cast<std::int64_t>(points.size());
    std::vector<int> owner(points.size(), 0);
    planesdf::detail::parallelChunks(m, threads, 4096, [&](int, long long begin, long long end) {
      for (long long j = begin; j < end; ++j) {
        const auto i = static_cast<std::size_t>(j);
        int o = 0;
        if (changed_world.nearest(points[i], o) <= kLabelDistance &&
            world.nearest(points[i], o) <= kLabelDistance && ids.count(o))
          owner[i] = o;
      }
    });
    return owner;
  }
};

/// `points` (reported frame) as `cloud`, and those with a nonzero owner as `gt` with the Int32
/// field "object_id".
void fillClouds(const std::vector<Vector3d>& points, const std::vector<int>& owners,
                PointCloud& cloud, PointCloud& gt) {
  cloud.points.reserve(points.size());
  std::vector<double> gt_ids;
  for (std::size_t j = 0; j < points.size(); ++j) {
    const Eigen::Vector3f p = points[j].cast<float>();
    cloud.points.push_back(p);
    if (owners[j] != 0) {
      gt.points.push_back(p);
      gt_ids.push_back(owners[j]);
    }
  }
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  gt.width = static_cast<std::uint32_t>(gt.points.size());
  gt.addField("object_id", ScalarType::Int32).values = std::move(gt_ids);
}

/// Voxels are truncated at this many voxels (the band the zero crossing is found in).
constexpr double kTruncationVoxels = 4.0;
/// Surface voxels must have been observed this often: a voxel seen by one frame only holds that
/// frame's noise and flying pixels unaveraged, while every surface an orbit covers is seen by
/// several consecutive frames.
constexpr int kMinWeight = 2;

/// Fuses the frames (reported poses) into a TSDF and extracts its surface (reported frame).
detail::TsdfSurface reconstruct(const SessionData& data, const SensorModel& sensor, double voxel,
                                int threads, std::string& stats) {
  detail::SparseTsdf tsdf(voxel, kTruncationVoxels * voxel, sensor.max_depth);
  for (std::size_t i = 0; i < data.frames.size(); ++i)
    tsdf.integrate(data.frames[i], data.reported_poses[i], threads);
  stats = std::to_string(tsdf.blockCount()) + " blocks, " +
          fixed(static_cast<double>(tsdf.bytes()) / (1 << 20), 0) + " MB";
  return tsdf.extractSurface(kMinWeight, threads);
}

/// Sets data.cloud and data.gt (see SessionData): built in the true frame, labelled there, written
/// in the reported frame (E). Returns the progress message.
std::string addWholeCloud(SessionData& data, const Pose& E, const Labeller& labeller,
                          const Intrinsics& K, int threads) {
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<Vector3d> points = wholeCloud(data, K, threads);
  const std::vector<int> owners = labeller.owners(points, threads);
  for (Vector3d& p : points) p = E * p;
  fillClouds(points, owners, data.cloud, data.gt);
  return "cloud " + std::to_string(data.cloud.size()) + " points, ground truth " +
         std::to_string(data.gt.size()) + " points on " + std::to_string(labeller.ids.size()) +
         " changed objects (" + fixed(secondsSince(t0), 1) + " s)";
}

/// Sets data.reconstruction, mesh_triangles and reconstruction_gt (see SessionData): fused with
/// the reported poses, labelled in the true frame (E^-1). Returns the progress message.
std::string addReconstruction(SessionData& data, const Pose& E, const Labeller& labeller,
                              const SensorModel& sensor, double voxel, int threads) {
  const auto t0 = std::chrono::steady_clock::now();
  std::string stats;
  detail::TsdfSurface surface = reconstruct(data, sensor, voxel, threads, stats);
  std::vector<Vector3d> true_points(surface.points.size());
  const Pose to_true = E.inverse();
  for (std::size_t i = 0; i < true_points.size(); ++i) true_points[i] = to_true * surface.points[i];
  fillClouds(surface.points, labeller.owners(true_points, threads), data.reconstruction,
             data.reconstruction_gt);
  data.mesh_triangles = std::move(surface.triangles);
  return "reconstruction (" + fixed(voxel * 1000.0, 1) + " mm TSDF, " + stats + ") " +
         std::to_string(data.reconstruction.size()) + " points, " +
         std::to_string(data.mesh_triangles.size()) + " triangles, ground truth " +
         std::to_string(data.reconstruction_gt.size()) + " points (" + fixed(secondsSince(t0), 1) +
         " s)";
}

SessionData simulateSession(const Scene& scene, int index, const std::vector<int>& changed_ids,
                            int threads, const SimulateOptions& options) {
  const Session& session = index == 0 ? scene.reference : scene.current;
  const std::string label = index == 0 ? "reference" : "current";
  const auto report = [&](const std::string& msg) {
    if (options.progress) options.progress(label + ": " + msg);
  };
  const detail::World world(sessionPrimitives(scene, session));
  SessionData data;
  data.true_poses = trajectoryPoses(session.trajectory);
  const Pose E = localisationErrorPose(session.localisation_error);
  const int n = static_cast<int>(data.true_poses.size());
  data.frames.resize(static_cast<std::size_t>(n));

  const auto t0 = std::chrono::steady_clock::now();
  planesdf::detail::parallelFor(n, threads, [&](int i) {
    const std::uint64_t seed = (std::uint64_t{scene.seed} << 32) |
                               (static_cast<std::uint64_t>(index) << 24) |
                               static_cast<std::uint64_t>(i);
    DepthFrame f = detail::renderFrame(world, scene.sensor,
                                       data.true_poses[static_cast<std::size_t>(i)], seed);
    f.timestamp = i / scene.sensor.frame_rate;
    data.frames[static_cast<std::size_t>(i)] = std::move(f);
  });
  for (const Pose& T : data.true_poses) data.reported_poses.push_back(E * T);
  report("rendered " + std::to_string(n) + " frames in " + fixed(secondsSince(t0), 1) + " s");

  const std::set<int> ids(changed_ids.begin(), changed_ids.end());
  std::vector<Primitive> changed_prims;
  for (const Object& o : session.objects)
    if (ids.count(o.id)) {
      const std::vector<Primitive> parts = objectPrimitives(o);
      changed_prims.insert(changed_prims.end(), parts.begin(), parts.end());
    }
  const detail::World changed_world(changed_prims);
  const Labeller labeller{world, changed_world, ids};

  report(addWholeCloud(data, E, labeller, scene.sensor.intrinsics, threads));
  report(addReconstruction(data, E, labeller, scene.sensor, options.reconstruction_voxel, threads));
  return data;
}

}  // namespace

Simulation simulate(const Scene& scene, const SimulateOptions& options) {
  validateScene(scene, "scene");
  const double voxel = options.reconstruction_voxel;
  if (!(voxel >= kMinReconstructionVoxel && voxel <= kMaxReconstructionVoxel))
    throw Error("", "SimulateOptions::reconstruction_voxel: " + std::to_string(voxel) +
                        " m is outside [" + fixed(kMinReconstructionVoxel, 3) + ", " +
                        fixed(kMaxReconstructionVoxel, 3) + "] m");
  const int threads = planesdf::detail::resolveThreads(options.threads);
  const ChangedIds changed = changedObjects(scene);
  Simulation sim;
  sim.reference = simulateSession(scene, 0, changed.reference, threads, options);
  sim.current = simulateSession(scene, 1, changed.current, threads, options);
  return sim;
}

void writeSimulation(const std::string& dir, const Scene& scene, const Simulation& simulation) {
  const fs::path root(dir);
  std::error_code ec;
  fs::create_directories(root / "gt", ec);
  if (ec || !fs::is_directory(root / "gt"))
    throw Error(dir, "cannot create the output folder: " +
                         (ec ? ec.message() : std::string("not a folder")));
  for (const auto& [data, label] :
       {std::pair<const SessionData*, const char*>{&simulation.reference, "reference"},
        {&simulation.current, "current"}}) {
    io::writeTumSequence((root / label).string(), data->frames, data->reported_poses);
    const std::string name(label);
    io::writePly((root / (name + ".ply")).string(), data->cloud);
    io::writePly((root / "gt" / (name + ".ply")).string(), data->gt);
    io::writePly((root / (name + "_recon.ply")).string(), data->reconstruction);
    io::writePly((root / "gt" / (name + "_recon.ply")).string(), data->reconstruction_gt);
    io::writePlyMesh((root / (name + "_mesh.ply")).string(), data->reconstruction,
                     data->mesh_triangles);
  }
  saveSceneJson((root / "scene.json").string(), scene);
}

}  // namespace planesdf::sim
