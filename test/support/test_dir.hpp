#pragma once
// A fresh directory for files a test writes: under $OCTOFUSE_TEST_TMP when set, else /tmp.

#include <sys/stat.h>

#include <cstdlib>
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

}  // namespace octofuse::test
