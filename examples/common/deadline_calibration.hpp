#pragma once
// The frame deadline's cost model as a file (--deadline-calibration FILE): written after a run
// from what the run learnt, read before one as its starting model. The config-file syntax
// (config_file.hpp), one rate a line, numbers in the shortest form that reads back as the same
// double, so a model read back is bit-identical to the one written:
//
//   # octofuse frame-deadline calibration: ... (pipeline/cost_model.hpp)
//   fixed_ms = 3.2
//   icp_fixed_ms = 0.4
//   icp_ms_per_mpixel_iteration = 23.4
//   integrate_fixed_ms = 4.1
//   integrate_ms_per_mvoxel = 10
//   raycast_fixed_ms = 6.5
//   raycast_ms_per_mstep = 76.6
//   free_space_fixed_ms = 0.2
//   free_space_ms_per_mvisit = 457
//   safety = 1

#include <string>

#include "octofuse/pipeline/cost_model.hpp"

namespace octofuse::examples {

std::string format_deadline_calibration(const CostModel& model);
// Every key once, no other key, each value a number validate(CostModel) accepts; false with
// `error` as "NAME:LINE: what is wrong" (or "NAME: ..." for a missing key).
bool parse_deadline_calibration(const std::string& text, const std::string& name, CostModel* model,
                                std::string* error);
// Reads `path`; false with `error` when it cannot be read or parsed.
bool read_deadline_calibration(const std::string& path, CostModel* model, std::string* error);
// Writes `path` whole or not at all (host::AtomicFile).
bool write_deadline_calibration(const std::string& path, const CostModel& model,
                                std::string* error);

}  // namespace octofuse::examples
