#pragma once
// Files a test writes: a fresh directory under $OCTOFUSE_TEST_TMP when set, else /tmp, and
// whole files written and read back byte for byte.

#include <sys/stat.h>
#include <unistd.h>

#include <cstdlib>
#include <fstream>
#include <iterator>
#include <string>

namespace octofuse::test {

inline std::string make_test_dir(const char* name) {
  const char* base = std::getenv("OCTOFUSE_TEST_TMP");
  std::string root = base != nullptr && base[0] != '\0' ? base : "/tmp";
  ::mkdir(root.c_str(), 0755);
  std::string pattern = root + "/" + name + "-XXXXXX";
  if (::mkdtemp(&pattern[0]) == nullptr) return std::string();
  return pattern;
}

inline void write_text(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

// The file's bytes; empty when it cannot be read.
inline std::string read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// True for anything at `path` (a file, a folder, a FIFO: none is opened).
inline bool file_exists(const std::string& path) {
  return ::access(path.c_str(), F_OK) == 0;
}

}  // namespace octofuse::test
