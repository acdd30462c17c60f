// Test-only: deliberately uses the exception machinery so the no-exceptions scan has something
// to find (the test that scans this library must fail).
#include <stdexcept>
#include <vector>

namespace octofuse_check {

int throwing_at(const std::vector<int>& values, int index);

int throwing_at(const std::vector<int>& values, int index) {
  if (index < 0) throw std::invalid_argument("negative index");
  return values.at(static_cast<std::size_t>(index));  // std::__throw_out_of_range_fmt
}

}  // namespace octofuse_check
