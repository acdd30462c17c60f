#pragma once
// Runs the octofuse-replay the build made as a child process (fork + exec), for the tests of what
// the program does with bad input, signals and kills. Also checks of its output files.

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <fcntl.h>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "support/test_dir.hpp"

namespace octofuse::test {

struct Child {
  pid_t pid = -1;
  std::string log_path;  // stdout and stderr together
};

// Starts octofuse-replay with `args`, its output going to `log_path`.
inline Child start_replay(const std::vector<std::string>& args, const std::string& log_path) {
  Child child;
  child.log_path = log_path;
  std::vector<std::string> argv_strings;
  argv_strings.push_back(OCTOFUSE_REPLAY_PATH);
  argv_strings.insert(argv_strings.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (std::string& a : argv_strings) argv.push_back(&a[0]);
  argv.push_back(nullptr);
  child.pid = ::fork();
  if (child.pid == 0) {
    const int fd = ::open(log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd >= 0) {
      ::dup2(fd, 1);
      ::dup2(fd, 2);
      ::close(fd);
    }
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  return child;
}

// The exit status (0-255), or 128 + the signal that ended it.
inline int wait_for(const Child& child) {
  int status = 0;
  if (::waitpid(child.pid, &status, 0) != child.pid) return -1;
  if (WIFEXITED(status)) return WEXITSTATUS(status);
  if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
  return -1;
}

inline std::string read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

struct RunResult {
  int exit_status = -1;
  std::string output;  // stdout and stderr
};

inline RunResult run_replay(const std::vector<std::string>& args, const std::string& log_path) {
  const Child child = start_replay(args, log_path);
  RunResult result;
  result.exit_status = wait_for(child);
  result.output = read_file(log_path);
  return result;
}

// Lines of `text` that start with `prefix`.
inline std::vector<std::string> lines_starting(const std::string& text, const std::string& prefix) {
  std::vector<std::string> out;
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind(prefix, 0) == 0) out.push_back(line);
  }
  return out;
}

// A strict JSON syntax check (RFC 8259 grammar, no extensions): true when `text` is one complete
// value with only whitespace around it. Enough to tell a whole stats.json from a cut one.
class JsonChecker {
 public:
  explicit JsonChecker(const std::string& text) : s_(text) {}
  bool valid() {
    skip();
    if (!value(0)) return false;
    skip();
    return i_ == s_.size();
  }

 private:
  bool value(int depth) {
    if (depth > 64 || i_ >= s_.size()) return false;
    const char c = s_[i_];
    if (c == '{') return object(depth);
    if (c == '[') return array(depth);
    if (c == '"') return string();
    if (c == '-' || (c >= '0' && c <= '9')) return number();
    return literal("true") || literal("false") || literal("null");
  }
  bool object(int depth) {
    ++i_;
    skip();
    if (peek('}')) return ++i_, true;
    for (;;) {
      skip();
      if (!string()) return false;
      skip();
      if (!peek(':')) return false;
      ++i_;
      skip();
      if (!value(depth + 1)) return false;
      skip();
      if (peek('}')) return ++i_, true;
      if (!peek(',')) return false;
      ++i_;
    }
  }
  bool array(int depth) {
    ++i_;
    skip();
    if (peek(']')) return ++i_, true;
    for (;;) {
      skip();
      if (!value(depth + 1)) return false;
      skip();
      if (peek(']')) return ++i_, true;
      if (!peek(',')) return false;
      ++i_;
    }
  }
  bool string() {
    if (!peek('"')) return false;
    for (++i_; i_ < s_.size(); ++i_) {
      const unsigned char c = static_cast<unsigned char>(s_[i_]);
      if (c == '"') return ++i_, true;
      if (c < 0x20) return false;
      if (c == '\\') ++i_;
    }
    return false;
  }
  bool number() {
    const std::size_t start = i_;
    if (peek('-')) ++i_;
    std::size_t digits = 0;
    while (i_ < s_.size() && ((s_[i_] >= '0' && s_[i_] <= '9') || s_[i_] == '.' || s_[i_] == 'e' ||
                              s_[i_] == 'E' || s_[i_] == '+' || s_[i_] == '-')) {
      digits += s_[i_] >= '0' && s_[i_] <= '9';
      ++i_;
    }
    return i_ > start && digits > 0;
  }
  bool literal(const char* word) {
    const std::string w(word);
    if (s_.compare(i_, w.size(), w) != 0) return false;
    i_ += w.size();
    return true;
  }
  bool peek(char c) const { return i_ < s_.size() && s_[i_] == c; }
  void skip() {
    while (i_ < s_.size() && (s_[i_] == ' ' || s_[i_] == '\n' || s_[i_] == '\r' || s_[i_] == '\t'))
      ++i_;
  }
  const std::string& s_;
  std::size_t i_ = 0;
};

}  // namespace octofuse::test
