#pragma once
// The dot product of two 3-vectors given as scalars, in the order Eigen 3.4 evaluates
// a.dot(b), a.squaredNorm() and each row of a 3x3 matrix times a vector (vectorisation off):
// its unrolled reduction splits three terms as a + (b + c). The ray tests, which run per pixel
// and primitive, are written with it instead of Eigen expressions: the same bits, and a sanitizer
// build does not pad and poison a stack temporary per vector operation.

namespace octofuse::sim {

inline double dot3(double ax, double ay, double az, double bx, double by, double bz) {
  return ax * bx + (ay * by + az * bz);
}

}  // namespace octofuse::sim
