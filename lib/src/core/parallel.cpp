#include "octofuse/core/parallel.hpp"

#include "octofuse/core/check.hpp"

#if defined(OCTOFUSE_HAVE_OPENMP)
#include <omp.h>
#endif

namespace octofuse {

WorkerTeam::WorkerTeam(int workers) : workers_(workers) {
  OCTOFUSE_CHECK(workers >= 1);
#if defined(OCTOFUSE_HAVE_OPENMP)
  // Start the OpenMP team now so thread creation is an init cost, not a first-frame one.
  if (workers_ > 1) {
    volatile int sink = 0;
#pragma omp parallel num_threads(workers_)
    { sink = omp_get_thread_num(); }
    (void)sink;
  }
#endif
}

void WorkerTeam::run(std::size_t task_count, void (*fn)(std::size_t, void*), void* context) const {
#if defined(OCTOFUSE_HAVE_OPENMP)
  if (workers_ > 1 && task_count > 1) {
    const long count = static_cast<long>(task_count);
#pragma omp parallel for num_threads(workers_) schedule(dynamic, 1)
    for (long task = 0; task < count; ++task) fn(static_cast<std::size_t>(task), context);
    return;
  }
#endif
  for (std::size_t task = 0; task < task_count; ++task) fn(task, context);
}

}  // namespace octofuse
