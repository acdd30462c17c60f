#pragma once
// Real recordings for tests: the folder named by OCTOFUSE_TEST_DATA_DIR (set by the build from the
// preset's data path) may be missing, empty, or hold other recordings than the one a test needs.
// Each such test asks for its recording by name and skips, with a warning, when it is not there.

#include <sys/stat.h>

#include <cstdlib>
#include <string>

namespace octofuse::test {

// The path of recording `name` inside the test data folder, or "" (and `why` says so) when the
// variable is unset or that recording is not a folder there.
inline std::string recording_dir(const char* name, std::string* why) {
  const char* data_dir = std::getenv("OCTOFUSE_TEST_DATA_DIR");
  if (data_dir == nullptr || data_dir[0] == '\0') {
    *why = "OCTOFUSE_TEST_DATA_DIR is not set";
    return std::string();
  }
  const std::string path = std::string(data_dir) + "/" + name;
  struct stat info {};
  if (::stat(path.c_str(), &info) != 0 || !S_ISDIR(info.st_mode)) {
    *why = path + " is not there";
    return std::string();
  }
  return path;
}

}  // namespace octofuse::test
