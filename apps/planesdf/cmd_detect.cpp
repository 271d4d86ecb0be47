// `planesdf detect REFERENCE CURRENT --out DIR [--config FILE]`: change detection between two
// sessions, with the outputs of design.md, "Formats" (changes.json, removed/added point PLYs,
// planes/*.png).
#include <chrono>
#include <cstdio>
#include <iostream>

#include "commands.hpp"
#include "planesdf/change.hpp"
#include "planesdf/error.hpp"
#include "session_input.hpp"
#include "timing.hpp"

namespace planesdf::cli {
namespace {

/// `detect -v`: each plane of a session map, with where it is and how far it reaches.
void printPlanes(const char* session, const Map& map) {
  for (const PlaneSdf& p : map.planes()) {
    const Plane& q = p.plane;
    const Eigen::Vector3d c =
        q.toWorld(Eigen::Vector3d(q.extent.center().x(), q.extent.center().y(), 0.0));
    const Eigen::Vector2d size = q.extent.isEmpty() ? Eigen::Vector2d(Eigen::Vector2d::Zero())
                                                    : Eigen::Vector2d(q.extent.sizes());
    std::fprintf(stderr,
                 "%s plane %d: %s, normal (%+.2f %+.2f %+.2f), offset %+.3f m, centre (%+.2f "
                 "%+.2f %+.2f), extent %.2f x %.2f m, %zu inliers\n",
                 session, q.id,
                 q.orientation == Plane::Orientation::Horizontal ? "horizontal" : "vertical",
                 q.normal.x(), q.normal.y(), q.normal.z(), q.offset, c.x(), c.y(), c.z(), size.x(),
                 size.y(), q.support);
  }
}

}  // namespace

int runDetect(const DetectArgs& args) {
  const Config cfg = resolveConfig(args.pipeline);
  const bool up_defaulted = upDefaulted(args.pipeline);
  const auto t0 = Clock::now();
  const Map reference =
      loadSession(args.reference, cfg, args.pipeline.intrinsics, "reference", up_defaulted);
  const Map current =
      loadSession(args.current, cfg, args.pipeline.intrinsics, "current", up_defaulted);
  const double load_ms = msSince(t0);
  if (reference.planes().empty())
    throw Error(args.reference,
                "no horizontal or vertical plane found (try --up auto or another --up)");
  if (current.planes().empty())
    throw Error(args.current,
                "no horizontal or vertical plane found (try --up auto or another --up)");

  DetectOptions options;
  options.keep_stages = true;
  const ChangeSet set = namingInput(args.reference + " and " + args.current, [&] {
    return detectChanges(reference, current, cfg, options);
  });
  const auto tw = Clock::now();
  writeChangeOutputs(args.out, set);
  const double write_ms = msSince(tw);

  if (args.verbose) {
    printPlanes("reference", reference);
    printPlanes("current", current);
    for (const PlanePairResult& r : set.pairs) {
      std::fprintf(stderr,
                   "%s plane %d -> %s plane %d: gap %+.3f m, in-plane %s (%.1f, %.1f cm, %.2f deg; "
                   "mismatched %d/%d -> %d/%d cells; best flips %d fixed, %d broken), %zu "
                   "blobs\n",
                   r.reference_to_current ? "reference" : "current", r.match.source_id,
                   r.reference_to_current ? "current" : "reference", r.match.target_id,
                   r.match.offset_gap, r.refinement.applied ? "refined" : "kept",
                   r.refinement.du * 100, r.refinement.dv * 100, r.refinement.dyaw * 57.29578,
                   r.refinement.mismatches_before, r.refinement.compared_before,
                   r.refinement.mismatches_after, r.refinement.compared_after, r.refinement.fixed,
                   r.refinement.broken, r.validations.size());
      for (std::size_t b = 0; b < r.validations.size(); ++b) {
        const BlobValidation& v = r.validations[b];
        std::fprintf(stderr,
                     "    blob %zu: %d cells%s, %s, similarity %.3f (%d of %d key voxels scored)",
                     b, b < r.change.blobs.size() ? r.change.blobs[b].area : -1,
                     b < r.change.blobs.size() && r.change.blobs[b].partial ? " (sliver)" : "",
                     toString(v.verdict), v.mean_similarity, v.scored, v.key_voxels);
        // How it compares with the other map's objects it lands on (sameInPlace).
        if (b < r.in_place.size() && r.in_place[b].target_cells > 0) {
          const InPlaceMatch& m = r.in_place[b];
          std::fprintf(stderr, "; on %d target cells: IoU %.2f, shift %.1f of %.1f cm, shape %.2f",
                       m.target_cells, m.overlap, m.shift * 100, m.size * 100, m.shape_distance);
        }
        std::fprintf(stderr, "\n");
      }
    }
  }
  std::printf("%zu changes (maps: %.0f ms, detect: %.0f ms, outputs: %.0f ms) -> %s\n",
              set.events.size(), load_ms, set.milliseconds, write_ms, args.out.c_str());
  for (const ChangeEvent& e : set.events) {
    const Eigen::Vector3d& c = e.primary().centroid;
    std::printf("  %3d  %-8s  plane %d  at (%+.3f %+.3f %+.3f)  %6zu points  confidence %.2f\n",
                e.id, toString(e.type), e.planeId(), c.x(), c.y(), c.z(), e.numPoints(),
                e.confidence);
  }
  return kExitOk;
}

}  // namespace planesdf::cli
