#pragma once
// --query-points FILE: points (one "x y z" per line, metres, world frame) answered against the
// final map into queries.txt, one "x y z STATE DISTANCE" line per point (query/map_query.hpp).

#include <string>
#include <vector>

#include <Eigen/Core>

#include "octofuse/query/map_query.hpp"

namespace octofuse::examples {

// Reads the points. Blank lines are skipped; any other line must hold exactly three finite
// numbers. False with `error` naming the file and line otherwise (or when it cannot be read).
bool load_query_points(const std::string& path, std::vector<Eigen::Vector3f>* points,
                       std::string* error);

// Answers every point and writes `path`; false with `error` when it cannot be written or a query
// fails.
template <typename VoxelT>
bool write_query_answers(const MapQuery<VoxelT>& query, const std::vector<Eigen::Vector3f>& points,
                         const std::string& path, std::string* error);

}  // namespace octofuse::examples
