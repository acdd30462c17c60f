#pragma once
// A fixed-size, allocation-free message buffer for the human side of an error ("depth/0001.png:
// truncated after 1024 bytes"). Components that can fail on input own one and expose it as
// `last_error()`.

#include <cstddef>

namespace octofuse {

class ErrorText {
 public:
  static constexpr std::size_t kCapacity = 256;

  // printf-style; truncates silently at kCapacity - 1 characters.
  void set(const char* format, ...) __attribute__((format(printf, 2, 3)));
  void clear() { text_[0] = '\0'; }
  const char* c_str() const { return text_; }
  bool empty() const { return text_[0] == '\0'; }

 private:
  char text_[kCapacity] = {};
};

}  // namespace octofuse
