#pragma once
// A small streaming JSON writer for stats.json: objects, arrays, numbers, booleans, null and
// strings with escaping. Commas and nesting are tracked; misuse (a value where a key is due,
// unbalanced end_*) is a programmer error and trips OCTOFUSE_CHECK.
//
//   JsonWriter json;
//   json.begin_object();
//   json.key("frames").value(42);
//   json.key("name").value("desk \"close\"");
//   json.end_object();
//   json.str();  // {"frames":42,"name":"desk \"close\""}

#include <cstdint>
#include <string>
#include <vector>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/status.hpp"

namespace octofuse::host {

class JsonWriter {
 public:
  JsonWriter& begin_object();
  JsonWriter& end_object();
  JsonWriter& begin_array();
  JsonWriter& end_array();
  JsonWriter& key(const char* name);

  // Non-finite numbers are written as null (JSON has no NaN or infinity).
  JsonWriter& value(double number);
  JsonWriter& value(std::int64_t number);
  JsonWriter& value(std::uint64_t number);
  JsonWriter& value(int number) { return value(static_cast<std::int64_t>(number)); }
  JsonWriter& value(bool boolean);
  JsonWriter& value(const char* text);
  JsonWriter& null();

  // The document so far; complete() when every begin_* has its end_* and one value was written.
  const std::string& str() const { return out_; }
  bool complete() const { return stack_.empty() && wrote_root_; }

  // Writes str() to `path`; failed_precondition when incomplete, unavailable / data_loss on I/O.
  Status write_file(const char* path, ErrorText* error) const;

  // Appends `text` as a quoted JSON string to `out` (quotes, backslash, control characters as
  // \uXXXX except \b \f \n \r \t; bytes >= 0x80 pass through as UTF-8).
  static void append_escaped(std::string* out, const char* text);

 private:
  void before_value();

  std::string out_;
  // One entry per open container: 'o' object awaiting key, 'v' object awaiting value, 'a' array.
  std::vector<char> stack_;
  std::vector<bool> first_;
  bool wrote_root_ = false;
};

}  // namespace octofuse::host
