// LZF (the format of PCL's binary_compressed PCD data) through liblzf, the format author's
// reference implementation packaged by Debian (see third_party_notes/liblzf.md). This wrapper
// adds planesdf's error convention and the exact-size check PCD needs.
#include <lzf.h>

#include <climits>
#include <string>

#include "planesdf/error.hpp"
#include "planesdf/io/pcd.hpp"

namespace planesdf::io {

std::string lzfCompress(const std::string& in) {
  if (in.empty()) return {};
  if (in.size() > UINT_MAX / 2) throw Error("", "lzf: input too large to compress");
  // liblzf never needs more than ~104% of the input; leave room for tiny inputs too.
  std::string out(in.size() + in.size() / 16 + 64, '\0');
  const unsigned n = lzf_compress(in.data(), static_cast<unsigned>(in.size()), out.data(),
                                  static_cast<unsigned>(out.size()));
  if (n == 0) throw Error("", "lzf: compression failed");
  out.resize(n);
  return out;
}

std::string lzfDecompress(const char* data, std::size_t size, std::size_t expected_size,
                          const std::string& name) {
  if (expected_size == 0) {
    if (size != 0) throw Error(name, "corrupt LZF data: data for an empty payload");
    return {};
  }
  if (size == 0) throw Error(name, "corrupt LZF data: no compressed bytes");
  if (size > UINT_MAX || expected_size > UINT_MAX)
    throw Error(name, "LZF payload larger than 4 GiB");
  // One LZF byte can stand for at most ~88 output bytes (a 3-byte back-reference of 264 bytes):
  // refuse to allocate for a declared size the stream cannot possibly hold.
  if (expected_size / 88 > size + 1)
    throw Error(name, "corrupt LZF data: " + std::to_string(size) + " bytes cannot expand to " +
                          std::to_string(expected_size));
  std::string out(expected_size, '\0');
  // liblzf checks input and output bounds (CHECK_INPUT) and returns 0 on corrupt data or when
  // the output would not fit.
  const unsigned n = lzf_decompress(data, static_cast<unsigned>(size), out.data(),
                                    static_cast<unsigned>(out.size()));
  if (n == 0)
    throw Error(name, "corrupt LZF data: stream does not decode into the declared " +
                          std::to_string(expected_size) + " bytes");
  if (n != expected_size)
    throw Error(name, "corrupt LZF data: decodes to " + std::to_string(n) + " bytes, header says " +
                          std::to_string(expected_size));
  return out;
}

}  // namespace planesdf::io
