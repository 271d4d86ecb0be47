#pragma once
/// \file atomic_file.hpp
/// Atomic output: write to a temporary file beside the target, then rename over it, so a
/// reader never sees a half-written output and a failed write leaves the old file in place.
/// Folders of outputs are built beside the target and swapped in the same way.

#include <functional>
#include <iosfwd>
#include <string>

namespace planesdf::io {

/// Calls `write(stream)` on a binary stream to a temporary file in the same folder as `path`,
/// flushes it, then puts it in place. The temporary file is anonymous (O_TMPFILE) while written;
/// a new `path` is then linked to it directly (a killed process leaves nothing), an existing one
/// is replaced by linking it as `.NAME.tmpXXXXXX` and renaming that over `path`. Where the file
/// system refuses O_TMPFILE the temporary file is named from the start. The temporary file is
/// locked while its writer runs; a replacement first removes the unlocked ones a killed run left
/// beside `path`. On any failure (the callback throws, the stream goes bad, the rename fails) the temporary file is
/// removed, `path` is untouched and planesdf::Error naming `path` is thrown (the callback's own
/// planesdf::Error passes through).
void writeFileAtomic(const std::string& path, const std::function<void(std::ostream&)>& write);

/// Builds a folder of outputs all or nothing: calls `build(tmp)` on a fresh sibling folder
/// `DIR.tmpXXXXXX`, then swaps it in for `dir` (renameat2 RENAME_EXCHANGE, or renaming the old
/// folder away and the new one in where the file system cannot exchange) and removes the old
/// folder. A reader sees the old folder or the new one, never a mix. An existing `dir` is
/// replaced only when `replaceable(dir)` accepts it. Sibling temporary folders of `dir` left by
/// killed runs are removed first (those a running process holds are locked and kept). On
/// failure the new folder is removed, `dir` is untouched and planesdf::Error naming `dir` (or
/// the callback's own error) is thrown.
void replaceFolderAtomic(const std::string& dir,
                         const std::function<void(const std::string&)>& build,
                         const std::function<bool(const std::string&)>& replaceable);

/// Reads a whole file into memory; throws planesdf::Error naming `path` when it is missing, not
/// a regular file or unreadable.
std::string readFile(const std::string& path);

/// Throws planesdf::Error naming `path` unless it is an existing regular file (or a link to
/// one): a FIFO or device would block or never end, a folder is a usage error.
void requireRegularFile(const std::string& path);

}  // namespace planesdf::io
