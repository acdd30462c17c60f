#pragma once
// Non-owning 2-D views over pixel buffers that live elsewhere (a source's ring, an arena).

#include <cstddef>
#include <cstdint>

#include "octofuse/core/check.hpp"

namespace octofuse {

template <typename T>
struct ImageView {
  T* data = nullptr;
  int width = 0;
  int height = 0;
  std::ptrdiff_t stride = 0;  // elements between row starts (>= width)

  ImageView() = default;
  ImageView(T* pixels, int w, int h, std::ptrdiff_t row_stride = 0)
      : data(pixels), width(w), height(h), stride(row_stride != 0 ? row_stride : w) {}
  // A view of T converts to a view of const T.
  template <typename U>
  ImageView(const ImageView<U>& other)  // NOLINT: implicit like a pointer conversion
      : data(other.data), width(other.width), height(other.height), stride(other.stride) {}

  bool empty() const { return data == nullptr || width <= 0 || height <= 0; }
  std::size_t pixel_count() const {
    return static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
  }
  T* row(int y) const { return data + y * stride; }
  T& operator()(int x, int y) const { return data[y * stride + x]; }
  T& at(int x, int y) const {
    OCTOFUSE_CHECK(x >= 0 && y >= 0 && x < width && y < height);
    return data[y * stride + x];
  }
};

}  // namespace octofuse
