#pragma once
// Opening a file to read that must be a regular file: a FIFO, a device or a folder given where a
// file is read (odometry, a map, a mesh, a calibration or configuration file) gets an error at
// once instead of blocking the program in open() or reading forever.

#include <cstdio>

namespace octofuse::host {

// The file open for reading ("rb"), or null with errno set: EISDIR for a folder, EINVAL for
// anything else that is not a regular file, or open()'s own errno.
std::FILE* open_regular_for_reading(const char* path);

// Why open_regular_for_reading() failed, for an error line: "not a regular file" for EINVAL,
// else strerror(error_number).
const char* open_failure_text(int error_number);

}  // namespace octofuse::host
