// A change-stage file whose includes all point down the pipeline: allowed.
#include "../plane/plane_internal.hpp"
#include "../numeric.hpp"
#include "planesdf/map.hpp"
