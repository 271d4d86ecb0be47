# The pipeline's layering, checked on every configure and as the CTest test `layering`
# (design.md, "Code layout"): each stage includes only itself and the stages below it.
#
#   base (src/*.cpp|hpp, the types/config/error/memory headers)
#   io -> plane, tsdf -> map -> height_map -> change -> adapters
#   eval and sim: tools beside the pipeline, on base and io only; only the CLI, tests, benches,
#   examples and the OctoMap baseline (adapters) use them.
#
# As a script: cmake -DPLANESDF_LAYERS_ROOT=<source dir> -P PlanesdfLayers.cmake
# exits non-zero naming every include that breaks a rule.
cmake_policy(SET CMP0057 NEW)  # if(IN_LIST)

set(_planesdf_layer_deps_base "base")
set(_planesdf_layer_deps_io "base")
set(_planesdf_layer_deps_plane "base;io")
set(_planesdf_layer_deps_tsdf "base;io")
set(_planesdf_layer_deps_map "base;io;plane;tsdf")
set(_planesdf_layer_deps_height_map "base;io;plane;tsdf;map")
set(_planesdf_layer_deps_change "base;io;plane;tsdf;map;height_map")
set(_planesdf_layer_deps_eval "base;io")
set(_planesdf_layer_deps_sim "base;io")
set(_planesdf_layer_deps_adapters "base;io;plane;tsdf;map;height_map;change;eval;adapters")

# The stage of a public header, by its path under include/ ("planesdf/map.hpp").
function(_planesdf_header_stage header out)
  string(REGEX REPLACE "^planesdf/" "" _h "${header}")
  if(_h MATCHES "^io/")
    set(_s io)
  elseif(_h MATCHES "^(mrpt|octomap)/")
    set(_s adapters)
  elseif(_h MATCHES "^(types|config|error|memory)\\.hpp$")
    set(_s base)
  elseif(_h STREQUAL "detail/tsdf_blocks.hpp")
    set(_s tsdf)  # internal storage behind tsdf.hpp
  elseif(_h MATCHES "^(plane|tsdf|map|height_map|sim)\\.hpp$")
    string(REGEX REPLACE "\\.hpp$" "" _s "${_h}")
  elseif(_h STREQUAL "config_io.hpp")
    set(_s map)  # validates every stage's part of the Config
  elseif(_h MATCHES "^(change|comparison|registration|validation|events|planesdf)\\.hpp$")
    set(_s change)  # planesdf.hpp: the umbrella of the core, whose top stage is change
  elseif(_h MATCHES "^(eval|baseline)\\.hpp$")
    set(_s eval)
  else()
    set(_s unknown)
  endif()
  set(${out} ${_s} PARENT_SCOPE)
endfunction()

# The stage of a file of the repository, by its path relative to the root.
function(_planesdf_file_stage rel out)
  if(rel MATCHES "^src/([a-z_]+)/")
    set(_s ${CMAKE_MATCH_1})
  elseif(rel MATCHES "^src/[^/]+$")
    set(_s base)
  elseif(rel MATCHES "^adapters/")
    set(_s adapters)
  elseif(rel MATCHES "^include/(.+)$")
    _planesdf_header_stage("${CMAKE_MATCH_1}" _s)
  else()
    set(_s unknown)
  endif()
  set(${out} ${_s} PARENT_SCOPE)
endfunction()

# Appends "file: includes X (stage S), which stage T may not use" lines to `violations_var`.
function(planesdf_check_layers root violations_var)
  file(GLOB_RECURSE _files RELATIVE ${root} ${root}/src/*.cpp ${root}/src/*.hpp
       ${root}/include/*.hpp ${root}/adapters/*.cpp ${root}/adapters/*.hpp)
  set(_violations)
  foreach(_rel ${_files})
    _planesdf_file_stage("${_rel}" _stage)
    if(_stage STREQUAL "unknown")
      list(APPEND _violations "${_rel}: a file of no known stage")
      continue()
    endif()
    file(STRINGS ${root}/${_rel} _lines REGEX "^#include [\"<]")
    foreach(_line ${_lines})
      if(_line MATCHES "^#include [\"<](planesdf/[^\">]+)[\">]")
        _planesdf_header_stage("${CMAKE_MATCH_1}" _dep)
      elseif(_line MATCHES "^#include \"\\.\\./([a-z_]+)/")
        set(_dep ${CMAKE_MATCH_1})
      elseif(_line MATCHES "^#include \"\\.\\./[^/]+\"")
        set(_dep base)
      else()
        continue()  # same folder, or a third-party / standard header
      endif()
      if(NOT _dep IN_LIST _planesdf_layer_deps_${_stage} AND NOT _dep STREQUAL _stage)
        string(REGEX REPLACE "^#include " "" _what "${_line}")
        list(APPEND _violations
             "${_rel}: includes ${_what} (stage ${_dep}), which stage ${_stage} may not use")
      endif()
    endforeach()
  endforeach()
  set(${violations_var} "${_violations}" PARENT_SCOPE)
endfunction()

if(CMAKE_SCRIPT_MODE_FILE AND PLANESDF_LAYERS_ROOT)
  planesdf_check_layers(${PLANESDF_LAYERS_ROOT} _v)
  if(_v)
    list(JOIN _v "\n  " _msg)
    message(FATAL_ERROR "pipeline layering broken:\n  ${_msg}")
  endif()
  message(STATUS "pipeline layering: every include points down the pipeline")
endif()
