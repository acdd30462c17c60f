#include "cli.hpp"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>

namespace octofuse::cli {

bool parse_double(const std::string& text, double min, double max, double& out) {
  if (text.empty()) return false;
  char* end = nullptr;
  errno = 0;
  const double value = std::strtod(text.c_str(), &end);
  if (errno != 0 || end != text.c_str() + text.size() || !std::isfinite(value)) return false;
  if (value < min || value > max) return false;
  out = value;
  return true;
}

bool parse_int(const std::string& text, std::int64_t min, std::int64_t max, std::int64_t& out) {
  if (text.empty()) return false;
  char* end = nullptr;
  errno = 0;
  const long long value = std::strtoll(text.c_str(), &end, 10);
  if (errno != 0 || end != text.c_str() + text.size()) return false;
  if (value < min || value > max) return false;
  out = value;
  return true;
}

bool parse_intrinsics(const std::string& text, double out[4]) {
  std::size_t start = 0;
  for (int i = 0; i < 4; ++i) {
    const std::size_t comma = text.find(',', start);
    const bool last = i == 3;
    if (last != (comma == std::string::npos)) return false;
    const std::string token = text.substr(start, last ? std::string::npos : comma - start);
    if (!parse_double(token, -1e6, 1e6, out[i])) return false;
    start = comma + 1;
  }
  return out[0] > 0.0 && out[1] > 0.0;
}

int fail(const std::string& message) {
  std::fprintf(stderr, "error: %s\n", message.c_str());
  return 2;
}

std::string format_option(const std::string& name, const char* value, const char* help) {
  constexpr std::size_t kHelpColumn = 23;
  std::string text = "  " + name;
  if (value != nullptr) text += std::string(" ") + value;
  const std::string indent(kHelpColumn, ' ');
  if (text.size() + 2 <= kHelpColumn) {
    text.resize(kHelpColumn, ' ');
  } else {
    text += "   ";
  }
  for (const char* c = help; *c != '\0'; ++c) {
    text += *c;
    if (*c == '\n' && c[1] != '\0') text += indent;
  }
  text += '\n';
  return text;
}

}  // namespace octofuse::cli
