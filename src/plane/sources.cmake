set(PLANESDF_PLANE_SOURCES plane.cpp knn_grid.cpp normals.cpp clustering.cpp ransac.cpp segment.cpp tracker.cpp refine.cpp front_face.cpp)
