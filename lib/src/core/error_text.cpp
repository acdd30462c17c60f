#include "octofuse/core/error_text.hpp"

#include <cstdarg>
#include <cstdio>

namespace octofuse {

void ErrorText::set(const char* format, ...) {
  va_list args;
  va_start(args, format);
  std::vsnprintf(text_, kCapacity, format, args);
  va_end(args);
}

}  // namespace octofuse
