set(PLANESDF_TSDF_SOURCES tsdf_volume.cpp fusion.cpp organized_cloud.cpp)
