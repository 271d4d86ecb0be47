// A plane-stage file that reaches up into the change stage: the layering check must name it.
#include "planesdf/change.hpp"
#include "planesdf/config.hpp"
