#pragma once
/// \file planesdf.hpp
/// Everything an application of the core library calls, in one include: the Config and its
/// JSON files, session maps from depth frames and clouds, height and object maps, change
/// detection (batch and incremental) with its events and outputs, and the input and output
/// formats. The simulator (`sim.hpp`) and the evaluator (`eval.hpp`, `baseline.hpp`) are
/// separate libraries; the MRPT and OctoMap adapters have their own headers.

#include "planesdf/change.hpp"
#include "planesdf/config.hpp"
#include "planesdf/config_io.hpp"
#include "planesdf/error.hpp"
#include "planesdf/events.hpp"
#include "planesdf/height_map.hpp"
#include "planesdf/io/cloud.hpp"
#include "planesdf/io/pcd.hpp"
#include "planesdf/io/ply.hpp"
#include "planesdf/io/tum.hpp"
#include "planesdf/map.hpp"
#include "planesdf/memory.hpp"
#include "planesdf/types.hpp"
