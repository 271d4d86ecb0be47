# Finds liblzf (Debian liblzf-dev: header in include/liblzf/lzf.h). Defines planesdf::lzf.
include(FindPackageHandleStandardArgs)
find_path(PlanesdfLZF_INCLUDE_DIR lzf.h PATH_SUFFIXES liblzf)
find_library(PlanesdfLZF_LIBRARY NAMES lzf)
find_package_handle_standard_args(PlanesdfLZF REQUIRED_VARS PlanesdfLZF_INCLUDE_DIR PlanesdfLZF_LIBRARY)
if(PlanesdfLZF_FOUND AND NOT TARGET planesdf::lzf)
  add_library(planesdf::lzf UNKNOWN IMPORTED)
  set_target_properties(planesdf::lzf PROPERTIES
    IMPORTED_LOCATION "${PlanesdfLZF_LIBRARY}"
    INTERFACE_INCLUDE_DIRECTORIES "${PlanesdfLZF_INCLUDE_DIR}")
endif()
mark_as_advanced(PlanesdfLZF_INCLUDE_DIR PlanesdfLZF_LIBRARY)
