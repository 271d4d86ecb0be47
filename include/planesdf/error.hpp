#pragma once
/// \file error.hpp
/// The project-wide error convention: every function that reads user input (files, folders,
/// flags) throws planesdf::Error on bad input. what() is one line of the form
/// "<path>: <element/line>: <what is wrong>" so a CLI can print it as-is. Nothing in planesdf
/// aborts the host process on bad input.

#include <stdexcept>
#include <string>

namespace planesdf {

class Error : public std::runtime_error {
 public:
  /// \param path  the file or folder the problem is in (may be empty for non-file input)
  /// \param message  what is wrong, including the line/element where known
  Error(std::string path, const std::string& message)
      : std::runtime_error(path.empty() ? message : path + ": " + message),
        path_(std::move(path)),
        message_(message) {}

  /// The file or folder named in the error ("" when the input was not a file).
  const std::string& path() const noexcept { return path_; }
  /// The message without the path prefix.
  const std::string& message() const noexcept { return message_; }

 private:
  std::string path_;
  std::string message_;
};

}  // namespace planesdf
