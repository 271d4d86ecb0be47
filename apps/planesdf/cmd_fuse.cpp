// `planesdf fuse`: being implemented (issue 3).
#include <iostream>

#include "commands.hpp"

namespace planesdf::cli {

int runFuse(const FuseArgs&) {
  std::cerr << "planesdf fuse: not implemented yet (issue 3)\n";
  return kExitUsage;
}

}  // namespace planesdf::cli
