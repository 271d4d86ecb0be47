// The fuzz configuration builds without Ceres: the plane refinement (src/plane/refine.cpp) is
// replaced by this stub. The parsers never fit planes (Map::deserialize restores saved planes), so
// reaching it means a target calls more than its parser, which is a fault of the target.
#include <cstdio>
#include <cstdlib>

#include "planesdf/plane.hpp"

namespace planesdf {

bool refinePlane(const std::vector<Eigen::Vector3f>&, Plane&, const Config&) {
  std::fputs("refinePlane reached in a fuzz target (built without Ceres)\n", stderr);
  std::abort();
}

}  // namespace planesdf
