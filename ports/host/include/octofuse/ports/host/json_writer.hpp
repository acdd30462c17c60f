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
//   json.c_str();  // {"frames":42,"name":"desk \"close\""}

#include <cstddef>
#include <cstdint>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/ports/host/host_buffer.hpp"

namespace octofuse::host {

class JsonWriter {
 public:
  JsonWriter& begin_object();
  JsonWriter& end_object();
  JsonWriter& begin_array();
  JsonWriter& end_array();
  JsonWriter& key(const char* name);

  // Non-finite numbers are written as null (JSON has no NaN or infinity).
  // Non-finite -> null; otherwise the shortest text that reads back as the same double, with a
  // '.' in any locale.
  JsonWriter& value(double number);
  JsonWriter& value(std::int64_t number);
  JsonWriter& value(std::uint64_t number);
  JsonWriter& value(int number) { return value(static_cast<std::int64_t>(number)); }
  JsonWriter& value(bool boolean);
  JsonWriter& value(const char* text);
  JsonWriter& null();

  // The document so far (NUL-terminated); complete() when every begin_* has its end_* and one
  // value was written.
  const char* c_str() const { return out_.empty() ? "" : out_.data(); }
  std::size_t size() const { return out_.empty() ? 0 : out_.size() - 1; }
  bool complete() const { return stack_.empty() && wrote_root_; }

  // Writes str() to `path`; failed_precondition when incomplete, unavailable / data_loss on I/O.
  Status write_file(const char* path, ErrorText* error) const;

 private:
  void before_value();
  void append(const char* text);
  void append(char c);
  // `text` as a quoted JSON string: quotes, backslash and control characters escaped (\b \f \n
  // \r \t, others as \u00XX); bytes >= 0x80 pass through as UTF-8.
  void append_escaped(const char* text);

  HostBuffer<char> out_;  // always NUL-terminated once anything was written
  // One entry per open container: 'o' object awaiting key, 'v' object awaiting value, 'a' array.
  HostBuffer<char> stack_;
  HostBuffer<unsigned char> first_;
  bool wrote_root_ = false;
};

}  // namespace octofuse::host
