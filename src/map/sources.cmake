set(PLANESDF_MAP_SOURCES map.cpp map_io.cpp config_io.cpp)
