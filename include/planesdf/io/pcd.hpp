#pragma once
/// \file pcd.hpp
/// PCD (PCL) point clouds without PCL: VERSION 0.5–0.7, DATA ascii, binary and
/// binary_compressed (LZF), organised (HEIGHT > 1) and unorganised. Fields x y z are required;
/// normal_x/y/z become normals; rgb (packed float) or rgba (packed uint) colours; every other
/// field (label, object_id, curvature, ...) is kept as a named ScalarField (a field with COUNT > 1
/// becomes name_0 .. name_{n-1}). NaN points stay in place as invalid points. VIEWPOINT
/// (tx ty tz qw qx qy qz) is the sensor pose in the cloud frame.

#include <string>

#include "planesdf/types.hpp"

namespace planesdf::io {

enum class PcdFormat { Ascii, Binary, BinaryCompressed };

/// Reads a PCD file. Throws planesdf::Error naming the file and what is wrong. Declared counts
/// (POINTS, WIDTH*HEIGHT, compressed sizes) are checked against the file size before allocating.
PointCloud readPcd(const std::string& path);

/// Parses PCD bytes already in memory; `name` is used in error messages.
PointCloud parsePcd(const std::string& bytes, const std::string& name);

/// Writes `cloud` atomically, keeping its width/height (organisation), VIEWPOINT, normals, colours
/// (as packed rgb) and ScalarFields with their types.
void writePcd(const std::string& path, const PointCloud& cloud,
              PcdFormat format = PcdFormat::BinaryCompressed);

/// LZF (liblzf format, as used by PCL's binary_compressed). Decompression throws
/// planesdf::Error naming `name` on corrupt input or when the output would not be exactly
/// `expected_size` bytes.
std::string lzfCompress(const std::string& in);
std::string lzfDecompress(const char* data, std::size_t size, std::size_t expected_size,
                          const std::string& name);

}  // namespace planesdf::io
