#pragma once
// Configuration files for the example programs: one `key = value` per line, where a key is a
// command-line option without its leading "--" and a flag takes `true` or `false`. Lines whose
// first non-blank character is '#' and blank lines are ignored; there is no inline comment (a
// '#' inside a value is part of it) and no quoting (the value is the rest of the line, trimmed).
//
//   # a deployment on the kitchen board
//   source = 7scenes:../shared/data/7scenes-redkitchen
//   voxel-size = 0.02
//   bilateral = true

#include <string>
#include <vector>

namespace octofuse::examples {

struct ConfigEntry {
  int line = 0;  // 1-based
  std::string key;
  std::string value;
};

// Splits `text` into entries. On a malformed line (no '=', empty key, a repeated key, a NUL or a
// line over 4096 bytes) returns false with `error` set to "NAME:LINE: what is wrong".
bool parse_config_text(const std::string& text, const std::string& name,
                       std::vector<ConfigEntry>* entries, std::string* error);

// Reads a file (at most 1 MiB) and parses it as above; `error` names the file on failure.
bool read_config_file(const std::string& path, std::vector<ConfigEntry>* entries,
                      std::string* error);

// Whether `value` can be written as the value of a config line and read back unchanged.
bool config_value_writable(const std::string& value);

}  // namespace octofuse::examples
