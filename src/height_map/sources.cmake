set(PLANESDF_HEIGHT_MAP_SOURCES height_map.cpp object_map.cpp roughness.cpp mask2d.cpp pictures.cpp)
