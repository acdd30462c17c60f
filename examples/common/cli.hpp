#pragma once
// Small command-line helpers shared by the example programs: strict number parsing (the whole
// token must parse, finite, in range) so a typo is an error, not a silent zero.

#include <cstdint>
#include <string>

namespace octofuse::cli {

bool parse_double(const std::string& text, double min, double max, double& out);
bool parse_int(const std::string& text, std::int64_t min, std::int64_t max, std::int64_t& out);
// "fx,fy,cx,cy" -> four finite values, fx and fy > 0.
bool parse_intrinsics(const std::string& text, double out[4]);

// Prints "error: <message>" to stderr; returns the exit code to use (2).
int fail(const std::string& message);

}  // namespace octofuse::cli
