#include "octofuse/ports/host/json_writer.hpp"

#include <cerrno>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstring>

#include "octofuse/core/check.hpp"

namespace octofuse::host {

void JsonWriter::before_value() {
  if (stack_.empty()) {
    OCTOFUSE_CHECK(!wrote_root_);  // one root value per document
    wrote_root_ = true;
    return;
  }
  if (stack_.back() == 'a') {
    if (!first_.back()) out_ += ',';
    first_.back() = false;
  } else {
    OCTOFUSE_CHECK(stack_.back() == 'v');  // a value inside an object needs a key first
    stack_.back() = 'o';
  }
}

JsonWriter& JsonWriter::begin_object() {
  before_value();
  out_ += '{';
  stack_.push_back('o');
  first_.push_back(true);
  return *this;
}

JsonWriter& JsonWriter::end_object() {
  OCTOFUSE_CHECK(!stack_.empty() && stack_.back() == 'o');
  out_ += '}';
  stack_.pop_back();
  first_.pop_back();
  return *this;
}

JsonWriter& JsonWriter::begin_array() {
  before_value();
  out_ += '[';
  stack_.push_back('a');
  first_.push_back(true);
  return *this;
}

JsonWriter& JsonWriter::end_array() {
  OCTOFUSE_CHECK(!stack_.empty() && stack_.back() == 'a');
  out_ += ']';
  stack_.pop_back();
  first_.pop_back();
  return *this;
}

JsonWriter& JsonWriter::key(const char* name) {
  OCTOFUSE_CHECK(!stack_.empty() && stack_.back() == 'o');
  if (!first_.back()) out_ += ',';
  first_.back() = false;
  append_escaped(&out_, name);
  out_ += ':';
  stack_.back() = 'v';
  return *this;
}

JsonWriter& JsonWriter::value(double number) {
  if (!std::isfinite(number)) return null();
  before_value();
  char text[32];
  // %.17g round-trips every double; integers print without a fraction.
  std::snprintf(text, sizeof(text), "%.17g", number);
  out_ += text;
  return *this;
}

JsonWriter& JsonWriter::value(std::int64_t number) {
  before_value();
  char text[24];
  std::snprintf(text, sizeof(text), "%" PRId64, number);
  out_ += text;
  return *this;
}

JsonWriter& JsonWriter::value(std::uint64_t number) {
  before_value();
  char text[24];
  std::snprintf(text, sizeof(text), "%" PRIu64, number);
  out_ += text;
  return *this;
}

JsonWriter& JsonWriter::value(bool boolean) {
  before_value();
  out_ += boolean ? "true" : "false";
  return *this;
}

JsonWriter& JsonWriter::value(const char* text) {
  before_value();
  append_escaped(&out_, text);
  return *this;
}

JsonWriter& JsonWriter::null() {
  before_value();
  out_ += "null";
  return *this;
}

void JsonWriter::append_escaped(std::string* out, const char* text) {
  *out += '"';
  for (const char* p = text; *p != '\0'; ++p) {
    const unsigned char c = static_cast<unsigned char>(*p);
    switch (c) {
      case '"':
        *out += "\\\"";
        break;
      case '\\':
        *out += "\\\\";
        break;
      case '\b':
        *out += "\\b";
        break;
      case '\f':
        *out += "\\f";
        break;
      case '\n':
        *out += "\\n";
        break;
      case '\r':
        *out += "\\r";
        break;
      case '\t':
        *out += "\\t";
        break;
      default:
        if (c < 0x20) {
          char code[8];
          std::snprintf(code, sizeof(code), "\\u%04x", c);
          *out += code;
        } else {
          *out += static_cast<char>(c);
        }
    }
  }
  *out += '"';
}

Status JsonWriter::write_file(const char* path, ErrorText* error) const {
  ErrorText scratch;
  ErrorText& err = error != nullptr ? *error : scratch;
  if (!complete()) {
    err.set("%s: JSON document is incomplete", path);
    return StatusCode::failed_precondition;
  }
  std::FILE* file = std::fopen(path, "w");
  if (file == nullptr) {
    err.set("%s: cannot create (%s)", path, std::strerror(errno));
    return StatusCode::unavailable;
  }
  bool ok = std::fwrite(out_.data(), 1, out_.size(), file) == out_.size();
  ok = std::fputc('\n', file) != EOF && ok;
  ok = std::fclose(file) == 0 && ok;
  if (!ok) {
    err.set("%s: write failed", path);
    return StatusCode::data_loss;
  }
  return ok_status();
}

}  // namespace octofuse::host
