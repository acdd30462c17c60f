#pragma once
// Death tests for Catch2 v2, which has none: run a statement in a fork()ed child and report how
// the child ended and what the check handler was told.

#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <csignal>
#include <cstdio>
#include <string>

#include "octofuse/core/check.hpp"

namespace octofuse::test {

struct ChildEnd {
  bool aborted = false;    // ended by SIGABRT
  int exit_code = -1;      // exit status when it ended normally
  std::string check_text;  // "file:line: expression" as the check handler received it
};

namespace death_detail {
inline int g_report_fd = -1;
inline void report_to_parent(const char* file, int line, const char* expression) {
  char text[512];
  const int n = std::snprintf(text, sizeof(text), "%s:%d: %s", file, line, expression);
  if (n > 0) {
    const std::size_t length = static_cast<std::size_t>(n) < sizeof(text) ? n : sizeof(text) - 1;
    (void)!write(g_report_fd, text, length);
  }
}
}  // namespace death_detail

// Runs fn() in a child with a check handler that reports to this process; the child exits 0 if
// fn returns. Catch2's own SIGABRT handler is removed in the child so it does not report there.
template <typename Fn>
ChildEnd run_in_child(Fn&& fn, bool install_reporting_handler = true) {
  ChildEnd end;
  int fds[2];
  if (pipe(fds) != 0) return end;
  std::fflush(nullptr);
  const pid_t pid = fork();
  if (pid == 0) {
    close(fds[0]);
    std::signal(SIGABRT, SIG_DFL);
    death_detail::g_report_fd = fds[1];
    if (install_reporting_handler) set_check_handler(&death_detail::report_to_parent);
    fn(fds[1]);
    _exit(0);
  }
  close(fds[1]);
  char buffer[512];
  ssize_t n = 0;
  while ((n = read(fds[0], buffer, sizeof(buffer))) > 0) {
    end.check_text.append(buffer, static_cast<std::size_t>(n));
  }
  close(fds[0]);
  int status = 0;
  if (pid > 0 && waitpid(pid, &status, 0) == pid) {
    end.aborted = WIFSIGNALED(status) && WTERMSIG(status) == SIGABRT;
    if (WIFEXITED(status)) end.exit_code = WEXITSTATUS(status);
  }
  return end;
}

}  // namespace octofuse::test
