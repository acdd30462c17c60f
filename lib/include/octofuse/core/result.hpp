#pragma once
// Result<T>: either a value or a non-ok Status. No exceptions, no heap.

#include <new>
#include <type_traits>
#include <utility>

#include "octofuse/core/check.hpp"
#include "octofuse/core/status.hpp"

namespace octofuse {

template <typename T>
class [[nodiscard]] Result {
  static_assert(!std::is_reference_v<T>, "Result<T&> is not supported; use Result<T*>");

 public:
  // A non-ok status. Passing ok here is a programmer error (there would be no value).
  constexpr Result(Status status) : status_(status) {  // NOLINT: implicit by design
    OCTOFUSE_CHECK(!status.ok());
  }
  constexpr Result(StatusCode code) : Result(Status(code)) {}             // NOLINT
  Result(const T& value) : status_() { new (&storage_) T(value); }        // NOLINT
  Result(T&& value) : status_() { new (&storage_) T(std::move(value)); }  // NOLINT

  Result(const Result& other) : status_(other.status_) {
    if (ok()) new (&storage_) T(other.value_unchecked());
  }
  Result(Result&& other) noexcept : status_(other.status_) {
    if (ok()) new (&storage_) T(std::move(other.value_unchecked()));
  }
  Result& operator=(const Result& other) {
    if (this != &other) {
      destroy();
      status_ = other.status_;
      if (ok()) new (&storage_) T(other.value_unchecked());
    }
    return *this;
  }
  Result& operator=(Result&& other) noexcept {
    if (this != &other) {
      destroy();
      status_ = other.status_;
      if (ok()) new (&storage_) T(std::move(other.value_unchecked()));
    }
    return *this;
  }
  ~Result() { destroy(); }

  constexpr bool ok() const { return status_.ok(); }
  constexpr Status status() const { return status_; }

  // Accessing the value of a failed Result is a programmer error and trips the check.
  T& value() & {
    OCTOFUSE_CHECK(ok());
    return value_unchecked();
  }
  const T& value() const& {
    OCTOFUSE_CHECK(ok());
    return value_unchecked();
  }
  T&& value() && {
    OCTOFUSE_CHECK(ok());
    return std::move(value_unchecked());
  }
  T value_or(T fallback) const { return ok() ? value_unchecked() : fallback; }

  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }

 private:
  T& value_unchecked() { return *std::launder(reinterpret_cast<T*>(&storage_)); }
  const T& value_unchecked() const { return *std::launder(reinterpret_cast<const T*>(&storage_)); }
  void destroy() {
    if (ok()) value_unchecked().~T();
  }

  Status status_;
  std::aligned_storage_t<sizeof(T), alignof(T)> storage_;
};

namespace internal {
inline constexpr Status to_status(Status s) {
  return s;
}
template <typename T>
constexpr Status to_status(const Result<T>& r) {
  return r.status();
}
}  // namespace internal

}  // namespace octofuse

#define OCTOFUSE_CONCAT_INNER(a, b) a##b
#define OCTOFUSE_CONCAT(a, b) OCTOFUSE_CONCAT_INNER(a, b)

// Returns the Status from the enclosing function when `expr` (a Status or Result) is not ok.
#define OCTOFUSE_TRY(expr)                                                                \
  do {                                                                                    \
    const ::octofuse::Status octofuse_try_status = ::octofuse::internal::to_status(expr); \
    if (!octofuse_try_status.ok()) return octofuse_try_status;                            \
  } while (false)

// `OCTOFUSE_TRY_ASSIGN(auto* block, pool.allocate());` declares/assigns lhs from a Result's
// value, or returns its Status from the enclosing function.
#define OCTOFUSE_TRY_ASSIGN(lhs, expr) \
  OCTOFUSE_TRY_ASSIGN_IMPL(OCTOFUSE_CONCAT(octofuse_try_result_, __LINE__), lhs, expr)
#define OCTOFUSE_TRY_ASSIGN_IMPL(tmp, lhs, expr) \
  auto tmp = (expr);                             \
  if (!tmp.ok()) return tmp.status();            \
  lhs = std::move(tmp).value()
