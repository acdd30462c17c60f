#pragma once
// --query-points FILE: points (one "x y z" per line, metres, world frame) answered against the
// final map into queries.txt, one "x y z STATE DISTANCE" line per point (query/map_query.hpp).

#include <string>
#include <vector>

#include <Eigen/Core>

#include "octofuse/query/esdf.hpp"
#include "octofuse/query/map_query.hpp"

namespace octofuse::examples {

// Reads the points. Blank lines are skipped; any other line must hold exactly three finite
// numbers. False with `error` naming the file and line otherwise (or when it cannot be read).
bool load_query_points(const std::string& path, std::vector<Eigen::Vector3f>* points,
                       std::string* error);

// Answers every point and writes `path`; false with `error` when it cannot be written or a query
// fails. With a distance field (query/esdf.hpp), a free point's DISTANCE is the larger of the
// two lower bounds: the free octant's and the field's distance less its error bound.
template <typename VoxelT>
bool write_query_answers(const MapQuery<VoxelT>& query, const std::vector<Eigen::Vector3f>& points,
                         const std::string& path, std::string* error,
                         const EsdfField* field = nullptr);

}  // namespace octofuse::examples
