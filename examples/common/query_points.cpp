#include "query_points.hpp"

#include <sys/stat.h>

#include "octofuse/ports/host/atomic_file.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>

namespace octofuse::examples {

namespace {
// The whole token must be a finite number.
bool parse_number(const std::string& token, float* out) {
  if (token.empty()) return false;
  char* end = nullptr;
  const double value = std::strtod(token.c_str(), &end);
  if (end == token.c_str() || *end != '\0' || !std::isfinite(value) || std::abs(value) > 1e30) {
    return false;
  }
  *out = static_cast<float>(value);
  return true;
}
}  // namespace

bool load_query_points(const std::string& path, std::vector<Eigen::Vector3f>* points,
                       std::string* error) {
  // A FIFO or device would block the open or never end: regular files only.
  struct stat info;
  if (::stat(path.c_str(), &info) == 0 && !S_ISREG(info.st_mode)) {
    *error = "cannot read query points from " + path + ": not a regular file";
    return false;
  }
  std::ifstream in(path);
  if (!in) {
    *error = "cannot read query points from " + path;
    return false;
  }
  std::string line;
  long number = 0;
  while (std::getline(in, line)) {
    ++number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream fields(line);
    std::string token;
    float values[3];
    int count = 0;
    bool good = true;
    while (fields >> token) {
      if (count == 3 || !parse_number(token, &values[count])) {
        good = false;
        break;
      }
      ++count;
    }
    if (good && count == 0) continue;  // blank line
    if (!good || count != 3) {
      *error = path + ":" + std::to_string(number) + ": expected 'x y z' (three finite numbers)";
      return false;
    }
    points->emplace_back(values[0], values[1], values[2]);
  }
  if (in.bad()) {
    *error = "cannot read query points from " + path;
    return false;
  }
  return true;
}

template <typename VoxelT>
bool write_query_answers(const MapQuery<VoxelT>& query, const std::vector<Eigen::Vector3f>& points,
                         const std::string& path, std::string* error, const EsdfField* field) {
  // Whole or not at all: a kill mid-write leaves no half-answered file.
  host::AtomicFile file;
  if (!file.open(path.c_str()).ok()) {
    *error = file.last_error();
    return false;
  }
  std::FILE* out = file.file();
  for (const Eigen::Vector3f& p : points) {
    const Result<PointAnswer> answer = query.point(p);
    if (!answer.ok()) {
      *error = std::string("query failed: ") + answer.status().name();
      return false;
    }
    float distance_m = answer.value().distance_m;
    if (answer.value().state == PointState::free && field != nullptr && field->reserved()) {
      // Both are lower bounds on the distance to the nearest surface seen: keep the larger.
      const Result<EsdfAnswer> far = field->distance(p);
      if (far.ok()) distance_m = std::max(distance_m, far.value().lower_bound_m);
    }
    std::fprintf(out, "%.6f %.6f %.6f %s %.6f\n", static_cast<double>(p.x()),
                 static_cast<double>(p.y()), static_cast<double>(p.z()),
                 point_state_name(answer.value().state), static_cast<double>(distance_m));
  }
  if (!file.commit().ok()) {
    *error = file.last_error();
    return false;
  }
  return true;
}

template bool write_query_answers(const MapQuery<TsdfVoxel>&, const std::vector<Eigen::Vector3f>&,
                                  const std::string&, std::string*, const EsdfField*);
template bool write_query_answers(const MapQuery<MultiresVoxel>&,
                                  const std::vector<Eigen::Vector3f>&, const std::string&,
                                  std::string*, const EsdfField*);
template bool write_query_answers(const MapQuery<Multires16Voxel>&,
                                  const std::vector<Eigen::Vector3f>&, const std::string&,
                                  std::string*, const EsdfField*);

}  // namespace octofuse::examples
