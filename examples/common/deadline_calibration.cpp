#include "deadline_calibration.hpp"
#include "octofuse/ports/host/read_file.hpp"

#include <charconv>
#include <cstdio>
#include <vector>

#include "cli.hpp"
#include "config_file.hpp"
#include "octofuse/ports/host/atomic_file.hpp"

namespace octofuse::examples {

namespace {

struct Field {
  const char* key;
  double& (*value)(CostModel& model);
  double min, max;  // accepted range (validate(CostModel) checks the whole again)
};

const Field kFields[] = {
    {"fixed_ms", [](CostModel& m) -> double& { return m.fixed_ms; }, 0.0, 1e6},
    {"icp_fixed_ms", [](CostModel& m) -> double& { return m.icp.fixed_ms; }, 0.0, 1e6},
    {"icp_ms_per_mpixel_iteration", [](CostModel& m) -> double& { return m.icp.ms_per_munit; },
     1e-300, 1e6},
    {"integrate_fixed_ms", [](CostModel& m) -> double& { return m.integrate.fixed_ms; }, 0.0, 1e6},
    {"integrate_ms_per_mvoxel", [](CostModel& m) -> double& { return m.integrate.ms_per_munit; },
     1e-300, 1e6},
    {"raycast_fixed_ms", [](CostModel& m) -> double& { return m.raycast.fixed_ms; }, 0.0, 1e6},
    {"raycast_ms_per_mstep", [](CostModel& m) -> double& { return m.raycast.ms_per_munit; }, 1e-300,
     1e6},
    {"free_space_fixed_ms", [](CostModel& m) -> double& { return m.free_space.fixed_ms; }, 0.0,
     1e6},
    {"free_space_ms_per_mvisit", [](CostModel& m) -> double& { return m.free_space.ms_per_munit; },
     1e-300, 1e6},
    {"safety", [](CostModel& m) -> double& { return m.safety; }, 1.0, 16.0},
};
constexpr int kFieldCount = static_cast<int>(sizeof(kFields) / sizeof(kFields[0]));

std::string shortest(double number) {
  char text[32];
  const auto result = std::to_chars(text, text + sizeof(text), number);
  return std::string(text, result.ptr);
}

}  // namespace

std::string format_deadline_calibration(const CostModel& model) {
  std::string text =
      "# octofuse frame-deadline calibration: per stage a fixed part (ms) and ms per million "
      "units; the frame's own fixed part; the safety factor\n";
  CostModel copy = model;
  for (const Field& field : kFields) {
    text += std::string(field.key) + " = " + shortest(field.value(copy)) + "\n";
  }
  return text;
}

bool parse_deadline_calibration(const std::string& text, const std::string& name, CostModel* model,
                                std::string* error) {
  std::vector<ConfigEntry> entries;
  if (!parse_config_text(text, name, &entries, error)) return false;
  CostModel parsed;
  bool seen[kFieldCount] = {};
  for (const ConfigEntry& entry : entries) {
    const std::string where = name + ":" + std::to_string(entry.line) + ": ";
    int index = -1;
    for (int i = 0; i < kFieldCount; ++i) {
      if (entry.key == kFields[i].key) index = i;
    }
    if (index < 0) {
      *error = where + "unknown key '" + entry.key + "'";
      return false;
    }
    const Field& field = kFields[index];
    double value = 0.0;
    if (!cli::parse_double(entry.value, field.min, field.max, value)) {
      const char* range = field.min >= 1.0 ? "[1, 16]" : field.min > 0.0 ? "(0, 1e6]" : "[0, 1e6]";
      *error = where + entry.key + " needs a number in " + range + ", not '" + entry.value + "'";
      return false;
    }
    field.value(parsed) = value;
    seen[index] = true;
  }
  for (int i = 0; i < kFieldCount; ++i) {
    if (!seen[i]) {
      *error = name + ": missing " + kFields[i].key;
      return false;
    }
  }
  ErrorText invalid;
  if (!validate(parsed, &invalid).ok()) {
    *error = name + ": " + invalid.c_str();
    return false;
  }
  *model = parsed;
  return true;
}

bool read_deadline_calibration(const std::string& path, CostModel* model, std::string* error) {
  std::FILE* file = host::open_regular_for_reading(path.c_str());
  if (file == nullptr) {
    *error = "cannot read deadline calibration " + path;
    return false;
  }
  std::string text;
  char chunk[4096];
  std::size_t got = 0;
  constexpr std::size_t kMaxBytes = 1 << 16;  // a calibration is a few hundred bytes
  while ((got = std::fread(chunk, 1, sizeof chunk, file)) > 0 && text.size() <= kMaxBytes) {
    text.append(chunk, got);
  }
  const bool failed = std::ferror(file) != 0;
  std::fclose(file);
  if (failed) {
    *error = "cannot read deadline calibration " + path;
    return false;
  }
  if (text.size() > kMaxBytes) {
    *error = path + ": too large for a deadline calibration";
    return false;
  }
  return parse_deadline_calibration(text, path, model, error);
}

bool write_deadline_calibration(const std::string& path, const CostModel& model,
                                std::string* error) {
  const std::string text = format_deadline_calibration(model);
  host::AtomicFile out;
  if (!out.open(path.c_str()).ok() || !out.write(text.data(), text.size()).ok() ||
      !out.commit().ok()) {
    *error = std::string("cannot write deadline calibration ") + path + ": " + out.last_error();
    return false;
  }
  return true;
}

}  // namespace octofuse::examples
