#pragma once
// Checks on the text of messages and outputs.

#include <string>

namespace octofuse::test {

inline bool contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

}  // namespace octofuse::test
