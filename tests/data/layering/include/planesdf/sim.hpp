// The simulator (a tool beside the pipeline) may not use the change stage.
#include "planesdf/events.hpp"
