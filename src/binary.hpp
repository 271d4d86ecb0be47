#pragma once
// Little binary writer and bounds-checked reader of trivially copyable values, shared by the
// map file format and the serialized change events.
#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <string>
#include <type_traits>

#include "planesdf/error.hpp"

namespace planesdf::detail {

class Writer {
 public:
  template <class T>
  void put(T v) {
    static_assert(std::is_trivially_copyable_v<T>);
    const std::size_t at = out.size();
    out.resize(at + sizeof(T));
    std::memcpy(&out[at], &v, sizeof(T));
  }
  void putVec(const Eigen::Vector3d& v) {
    for (int i = 0; i < 3; ++i) put<double>(v[i]);
  }
  void putBytes(const void* p, std::size_t n) { out.append(static_cast<const char*>(p), n); }
  std::string out;
};

class Reader {
 public:
  /// Reads bytes[begin, end); errors are planesdf::Error(name, "corrupt <kind>: ...").
  Reader(const char* bytes, std::size_t begin, std::size_t end, const std::string& name,
         const char* kind = "map")
      : b_(bytes), pos_(begin), end_(end), name_(name), kind_(kind) {}
  template <class T>
  T get(const char* what) {
    need(sizeof(T), what);
    T v;
    std::memcpy(&v, &b_[pos_], sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  Eigen::Vector3d getVec(const char* what) {
    Eigen::Vector3d v;
    for (int i = 0; i < 3; ++i) v[i] = get<double>(what);
    return v;
  }
  const char* take(std::size_t n, const char* what) {
    need(n, what);
    const char* p = &b_[pos_];
    pos_ += n;
    return p;
  }
  /// Throws unless `count` items of `item_bytes` each fit in what is left.
  void needItems(std::uint64_t count, std::size_t item_bytes, const char* what) {
    if (item_bytes > 0 && count > (end_ - pos_) / item_bytes)
      fail(std::string(what) + " count " + std::to_string(count) + " exceeds the file size");
  }
  std::size_t remaining() const { return end_ - pos_; }
  [[noreturn]] void fail(const std::string& msg) const {
    throw Error(name_, std::string("corrupt ") + kind_ + ": " + msg + " (at byte " +
                           std::to_string(pos_) + ")");
  }

 private:
  void need(std::size_t n, const char* what) {
    if (end_ - pos_ < n) fail(std::string("truncated while reading ") + what);
  }
  const char* b_;
  std::size_t pos_, end_;
  const std::string& name_;
  const char* kind_;
};

/// A regular file's bytes mapped read-only and pre-faulted (MAP_POPULATE): a map of hundreds of
/// MB is read without a zero-filled buffer and a copy into it, each page a fault on a virtual
/// machine. ok() is false when the file cannot be mapped (missing, a folder, empty, not Linux):
/// the caller then reads it the plain way, which names the problem.

}  // namespace planesdf::detail
