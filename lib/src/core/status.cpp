#include "octofuse/core/status.hpp"

namespace octofuse {

const char* status_code_name(StatusCode code) {
  switch (code) {
    case StatusCode::ok:
      return "ok";
    case StatusCode::invalid_argument:
      return "invalid_argument";
    case StatusCode::out_of_range:
      return "out_of_range";
    case StatusCode::resource_exhausted:
      return "resource_exhausted";
    case StatusCode::unavailable:
      return "unavailable";
    case StatusCode::data_loss:
      return "data_loss";
    case StatusCode::end_of_stream:
      return "end_of_stream";
    case StatusCode::deadline_exceeded:
      return "deadline_exceeded";
    case StatusCode::failed_precondition:
      return "failed_precondition";
    case StatusCode::internal:
      return "internal";
  }
  return "unknown";
}

}  // namespace octofuse
