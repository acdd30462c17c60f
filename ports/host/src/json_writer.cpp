#include "octofuse/ports/host/json_writer.hpp"

#include "octofuse/ports/host/atomic_file.hpp"

#include <cerrno>
#include <charconv>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstring>

#include "octofuse/core/check.hpp"

namespace octofuse::host {

void JsonWriter::append(char c) {
  if (!out_.empty()) out_.resize(out_.size() - 1);  // drop the NUL
  out_.push_back(c);
  out_.push_back('\0');
}

void JsonWriter::append(const char* text) {
  for (const char* p = text; *p != '\0'; ++p) append(*p);
}

void JsonWriter::before_value() {
  if (stack_.empty()) {
    OCTOFUSE_CHECK(!wrote_root_);  // one root value per document
    wrote_root_ = true;
    return;
  }
  if (stack_.back() == 'a') {
    if (!first_.back()) append(',');
    first_.back() = 0;
  } else {
    OCTOFUSE_CHECK(stack_.back() == 'v');  // a value inside an object needs a key first
    stack_.back() = 'o';
  }
}

JsonWriter& JsonWriter::begin_object() {
  before_value();
  append('{');
  stack_.push_back('o');
  first_.push_back(1);
  return *this;
}

JsonWriter& JsonWriter::end_object() {
  OCTOFUSE_CHECK(!stack_.empty() && stack_.back() == 'o');
  append('}');
  stack_.resize(stack_.size() - 1);
  first_.resize(first_.size() - 1);
  return *this;
}

JsonWriter& JsonWriter::begin_array() {
  before_value();
  append('[');
  stack_.push_back('a');
  first_.push_back(1);
  return *this;
}

JsonWriter& JsonWriter::end_array() {
  OCTOFUSE_CHECK(!stack_.empty() && stack_.back() == 'a');
  append(']');
  stack_.resize(stack_.size() - 1);
  first_.resize(first_.size() - 1);
  return *this;
}

JsonWriter& JsonWriter::key(const char* name) {
  OCTOFUSE_CHECK(!stack_.empty() && stack_.back() == 'o');
  if (!first_.back()) append(',');
  first_.back() = 0;
  append_escaped(name);
  append(':');
  stack_.back() = 'v';
  return *this;
}

JsonWriter& JsonWriter::value(double number) {
  if (!std::isfinite(number)) return null();
  before_value();
  // The shortest text that reads back as the same double ("7.527", not "7.5270000000000001"),
  // integers without a fraction, and a '.' whatever the C locale of the moment says.
  char text[32];
  const std::to_chars_result result = std::to_chars(text, text + sizeof(text) - 1, number);
  *result.ptr = '\0';
  append(text);
  return *this;
}

JsonWriter& JsonWriter::value(std::int64_t number) {
  before_value();
  char text[24];
  std::snprintf(text, sizeof(text), "%" PRId64, number);
  append(text);
  return *this;
}

JsonWriter& JsonWriter::value(std::uint64_t number) {
  before_value();
  char text[24];
  std::snprintf(text, sizeof(text), "%" PRIu64, number);
  append(text);
  return *this;
}

JsonWriter& JsonWriter::value(bool boolean) {
  before_value();
  append(boolean ? "true" : "false");
  return *this;
}

JsonWriter& JsonWriter::value(const char* text) {
  before_value();
  append_escaped(text);
  return *this;
}

JsonWriter& JsonWriter::null() {
  before_value();
  append("null");
  return *this;
}

void JsonWriter::append_escaped(const char* text) {
  append('"');
  for (const char* p = text; *p != '\0'; ++p) {
    const unsigned char c = static_cast<unsigned char>(*p);
    switch (c) {
      case '"':
        append("\\\"");
        break;
      case '\\':
        append("\\\\");
        break;
      case '\b':
        append("\\b");
        break;
      case '\f':
        append("\\f");
        break;
      case '\n':
        append("\\n");
        break;
      case '\r':
        append("\\r");
        break;
      case '\t':
        append("\\t");
        break;
      default:
        if (c < 0x20) {
          char code[8];
          std::snprintf(code, sizeof(code), "\\u%04x", c);
          append(code);
        } else {
          append(static_cast<char>(c));
        }
    }
  }
  append('"');
}

Status JsonWriter::write_file(const char* path, ErrorText* error) const {
  ErrorText scratch;
  ErrorText& err = error != nullptr ? *error : scratch;
  if (!complete()) {
    err.set("%s: JSON document is incomplete", path);
    return StatusCode::failed_precondition;
  }
  // Through a temporary renamed into place: a crash leaves the previous file or this one, whole.
  AtomicFile out;
  Status status = out.open(path);
  if (status.ok()) status = out.write(c_str(), size());
  if (status.ok()) status = out.write("\n", 1);
  if (status.ok()) status = out.commit();
  if (!status.ok()) err.set("%s", out.last_error());
  return status;
}

}  // namespace octofuse::host
