#pragma once
// Errors are values. A Status is one byte: a code from a small fixed set, no message, no
// allocation. Human-readable detail, where a caller needs it, travels separately in an
// ErrorText (error_text.hpp) that the failing component owns.

#include <cstdint>

namespace octofuse {

enum class StatusCode : std::uint8_t {
  ok = 0,
  invalid_argument,     // the caller passed something malformed (bad size, NaN, non-rigid pose)
  out_of_range,         // a valid value outside what this object covers (point outside the map)
  resource_exhausted,   // a fixed pool, buffer or budget is full
  unavailable,          // a device or file is not there (yet); retrying may help
  data_loss,            // data was read but is corrupt or truncated
  end_of_stream,        // no more frames
  deadline_exceeded,    // a wait ran out of time
  failed_precondition,  // called in the wrong state (next() before open())
  internal,             // an invariant broke; the object stays usable but the result is void
};

inline constexpr int kStatusCodeCount = 10;

// Stable lower-case name of a code ("resource_exhausted"); never null.
const char* status_code_name(StatusCode code);

class [[nodiscard]] Status {
 public:
  constexpr Status() = default;
  constexpr Status(StatusCode code) : code_(code) {}  // NOLINT: implicit by design

  constexpr bool ok() const { return code_ == StatusCode::ok; }
  constexpr StatusCode code() const { return code_; }
  const char* name() const { return status_code_name(code_); }

  // Marks a Status as deliberately dropped, so [[nodiscard]] stays meaningful elsewhere.
  constexpr void ignore() const {}

  friend constexpr bool operator==(Status a, Status b) { return a.code_ == b.code_; }
  friend constexpr bool operator!=(Status a, Status b) { return a.code_ != b.code_; }

 private:
  StatusCode code_ = StatusCode::ok;
};

constexpr Status ok_status() {
  return Status();
}

}  // namespace octofuse
