#pragma once
// writeFileAtomic with the choice of temporary file exposed, so tests cover both paths.

#include <functional>
#include <iosfwd>
#include <string>

namespace planesdf::io {

/// As writeFileAtomic(path, write); `allow_anonymous = false` forces the named temporary file
/// used when the file system refuses O_TMPFILE.
void writeFileAtomic(const std::string& path, const std::function<void(std::ostream&)>& write,
                     bool allow_anonymous);

}  // namespace planesdf::io
