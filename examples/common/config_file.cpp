#include "config_file.hpp"
#include "octofuse/ports/host/read_file.hpp"

#include <cstdio>

namespace octofuse::examples {

namespace {

constexpr std::size_t kMaxLineBytes = 4096;
constexpr long kMaxFileBytes = 1 << 20;

bool is_blank(char c) {
  return c == ' ' || c == '\t' || c == '\r';
}

std::string trim(const std::string& text) {
  std::size_t begin = 0;
  std::size_t end = text.size();
  while (begin < end && is_blank(text[begin])) ++begin;
  while (end > begin && is_blank(text[end - 1])) --end;
  return text.substr(begin, end - begin);
}

}  // namespace

bool parse_config_text(const std::string& text, const std::string& name,
                       std::vector<ConfigEntry>* entries, std::string* error) {
  entries->clear();
  auto fail = [&](int line, const std::string& message) {
    *error = name + ":" + std::to_string(line) + ": " + message;
    return false;
  };
  std::size_t start = 0;
  int line_number = 0;
  while (start < text.size()) {
    ++line_number;
    std::size_t end = text.find('\n', start);
    if (end == std::string::npos) end = text.size();
    const std::string raw = text.substr(start, end - start);
    start = end + 1;
    if (raw.size() > kMaxLineBytes) return fail(line_number, "line longer than 4096 bytes");
    if (raw.find('\0') != std::string::npos) return fail(line_number, "NUL byte in line");
    const std::string line = trim(raw);
    if (line.empty() || line[0] == '#') continue;
    const std::size_t equals = line.find('=');
    if (equals == std::string::npos) {
      return fail(line_number, "expected 'key = value', got '" + line + "'");
    }
    ConfigEntry entry;
    entry.line = line_number;
    entry.key = trim(line.substr(0, equals));
    entry.value = trim(line.substr(equals + 1));
    if (entry.key.empty()) return fail(line_number, "missing key before '='");
    for (const ConfigEntry& earlier : *entries) {
      if (earlier.key == entry.key) {
        return fail(line_number,
                    "'" + entry.key + "' already set on line " + std::to_string(earlier.line));
      }
    }
    entries->push_back(entry);
  }
  return true;
}

bool read_config_file(const std::string& path, std::vector<ConfigEntry>* entries,
                      std::string* error) {
  std::FILE* file = host::open_regular_for_reading(path.c_str());
  if (file == nullptr) {
    *error = "cannot open config file '" + path + "'";
    return false;
  }
  std::string text;
  char buffer[4096];
  std::size_t got = 0;
  bool too_big = false;
  while ((got = std::fread(buffer, 1, sizeof(buffer), file)) > 0) {
    text.append(buffer, got);
    if (static_cast<long>(text.size()) > kMaxFileBytes) {
      too_big = true;
      break;
    }
  }
  const bool read_error = std::ferror(file) != 0;
  std::fclose(file);
  if (too_big) {
    *error = "config file '" + path + "' is larger than 1 MiB";
    return false;
  }
  if (read_error) {
    *error = "cannot read config file '" + path + "'";
    return false;
  }
  return parse_config_text(text, path, entries, error);
}

bool config_value_writable(const std::string& value) {
  if (value.size() > kMaxLineBytes / 2) return false;
  for (const char c : value) {
    if (c == '\n' || c == '\0') return false;
  }
  return value.empty() || (!is_blank(value.front()) && !is_blank(value.back()));
}

}  // namespace octofuse::examples
