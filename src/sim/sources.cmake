set(PLANESDF_SIM_SOURCES scene.cpp preset.cpp scene_json.cpp geometry.cpp world.cpp render.cpp reconstruct.cpp
    simulate.cpp)
