#pragma once
/// \file ply.hpp
/// PLY point clouds without PCL/Open3D. Reads ascii, binary_little_endian and binary_big_endian;
/// properties char/uchar/short/ushort/int/uint/float/double (and int8..float64 aliases). Vertex
/// properties x y z are required; nx ny nz become normals, red green blue (or r g b,
/// diffuse_*) colours; every other scalar vertex property (object_id, change_id, ...) is kept as a
/// named ScalarField with its type. Other elements (faces, ...) are skipped, list properties
/// included.

#include <string>
#include <vector>

#include "planesdf/types.hpp"

namespace planesdf::io {

enum class PlyFormat { Ascii, BinaryLittleEndian, BinaryBigEndian };

/// Reads a PLY file. Throws planesdf::Error naming the file and what is wrong (missing file, bad
/// magic, unsupported type, a declared count larger than the file can hold, truncated data,
/// non-numeric values, ...). Declared counts are checked against the file size before allocating.
PointCloud readPly(const std::string& path);

/// Parses PLY bytes already in memory; `name` is used in error messages.
PointCloud parsePly(const std::string& bytes, const std::string& name);

/// Writes `cloud` atomically (temporary file + rename): x y z as float, normals, colours as
/// uchar, every ScalarField with its own type. Throws planesdf::Error on failure.
void writePly(const std::string& path, const PointCloud& cloud,
              PlyFormat format = PlyFormat::BinaryLittleEndian);

/// Writes a triangle mesh atomically: `vertices` as the vertex element (as writePly writes a
/// cloud), then a face element of `triangles` (`property list uchar int vertex_indices`).
/// readPly reads the vertices back and skips the faces. Throws planesdf::Error when a triangle
/// indexes a vertex that does not exist or there are more vertices than an int can index.
void writePlyMesh(const std::string& path, const PointCloud& vertices,
                  const std::vector<Triangle>& triangles,
                  PlyFormat format = PlyFormat::BinaryLittleEndian);

}  // namespace planesdf::io
