set(PLANESDF_CHANGE_SOURCES validation.cpp registration.cpp inplane_refinement.cpp comparison.cpp change.cpp plane_maps.cpp assemble.cpp session.cpp change_io.cpp event_io.cpp detector.cpp)
