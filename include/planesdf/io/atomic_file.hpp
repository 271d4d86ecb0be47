#pragma once
/// \file atomic_file.hpp
/// Atomic output: write to a temporary file beside the target, then rename over it, so a
/// reader never sees a half-written output and a failed write leaves the old file in place.

#include <functional>
#include <iosfwd>
#include <string>

namespace planesdf::io {

/// Calls `write(stream)` on a binary stream to a temporary file in the same folder as `path`,
/// flushes it, then renames it to `path`. On any failure (the callback throws, the stream goes
/// bad, the rename fails) the temporary file is removed, `path` is untouched and
/// planesdf::Error naming `path` is thrown (the callback's own planesdf::Error passes through).
void writeFileAtomic(const std::string& path, const std::function<void(std::ostream&)>& write);

/// Reads a whole file into memory; throws planesdf::Error naming `path` when it is missing, not
/// a regular file or unreadable.
std::string readFile(const std::string& path);

/// Throws planesdf::Error naming `path` unless it is an existing regular file (or a link to
/// one): a FIFO or device would block or never end, a folder is a usage error.
void requireRegularFile(const std::string& path);

}  // namespace planesdf::io
