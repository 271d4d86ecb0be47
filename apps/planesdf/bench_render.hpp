#pragma once
// The simulated sessions `planesdf bench` fuses: frames rendered once, before anything is timed.
#include <string>
#include <vector>

#include "planesdf/sim.hpp"
#include "planesdf/types.hpp"

namespace planesdf::cli {

/// The rendered frames of one simulated session, with the true and the reported camera poses.
struct Sequence {
  std::vector<DepthFrame> frames;
  std::vector<Pose> true_poses;
  std::vector<Pose> poses;  ///< reported (the session's localisation error applied)
};

/// Renders the first `max_frames` frames of `session` (0: all), progress on stderr as `label`.
Sequence renderSession(const sim::Scene& scene, const sim::Session& session, int session_index,
                       int max_frames, const std::string& label);

}  // namespace planesdf::cli
