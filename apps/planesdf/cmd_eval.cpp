// `planesdf eval`: being implemented (issue 4).
#include <iostream>

#include "commands.hpp"

namespace planesdf::cli {

int runEval(const EvalArgs&) {
  std::cerr << "planesdf eval: not implemented yet (issue 4)\n";
  return kExitUsage;
}

}  // namespace planesdf::cli
