# Finds the three OpenCV 4 libraries planesdf uses (core, imgproc, imgcodecs) from Debian's narrow
# -dev packages, which ship no OpenCVConfig.cmake. Defines imported targets
#   planesdf::opencv_core, planesdf::opencv_imgproc, planesdf::opencv_imgcodecs
# and PlanesdfOpenCV_FOUND / PlanesdfOpenCV_INCLUDE_DIR.
include(FindPackageHandleStandardArgs)

find_path(PlanesdfOpenCV_INCLUDE_DIR opencv2/core.hpp PATH_SUFFIXES opencv4)
foreach(_m core imgproc imgcodecs)
  find_library(PlanesdfOpenCV_${_m}_LIBRARY NAMES opencv_${_m})
endforeach()

find_package_handle_standard_args(PlanesdfOpenCV
  REQUIRED_VARS PlanesdfOpenCV_INCLUDE_DIR PlanesdfOpenCV_core_LIBRARY
                PlanesdfOpenCV_imgproc_LIBRARY PlanesdfOpenCV_imgcodecs_LIBRARY)

if(PlanesdfOpenCV_FOUND)
  foreach(_m core imgproc imgcodecs)
    if(NOT TARGET planesdf::opencv_${_m})
      add_library(planesdf::opencv_${_m} UNKNOWN IMPORTED)
      set_target_properties(planesdf::opencv_${_m} PROPERTIES
        IMPORTED_LOCATION "${PlanesdfOpenCV_${_m}_LIBRARY}"
        INTERFACE_INCLUDE_DIRECTORIES "${PlanesdfOpenCV_INCLUDE_DIR}")
    endif()
  endforeach()
  set_property(TARGET planesdf::opencv_imgproc APPEND PROPERTY INTERFACE_LINK_LIBRARIES planesdf::opencv_core)
  set_property(TARGET planesdf::opencv_imgcodecs APPEND PROPERTY INTERFACE_LINK_LIBRARIES planesdf::opencv_core)
endif()
mark_as_advanced(PlanesdfOpenCV_INCLUDE_DIR)
