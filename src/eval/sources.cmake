set(PLANESDF_EVAL_SOURCES eval.cpp baseline.cpp)
