#pragma once
// Small command-line helpers shared by the example programs: strict number parsing (the whole
// token must parse, finite, in range) so a typo is an error, not a silent zero.

#include <cstddef>
#include <cstdint>
#include <string>

namespace octofuse::cli {

bool parse_double(const std::string& text, double min, double max, double& out);
bool parse_int(const std::string& text, std::int64_t min, std::int64_t max, std::int64_t& out);
// "fx,fy,cx,cy" -> four finite values, fx and fy > 0.
bool parse_intrinsics(const std::string& text, double out[4]);

// Prints "error: <message>" to stderr; returns the exit code to use (2).
int fail(const std::string& message);

// The usage lines of one option: "  --name VALUE" and its help in a column beside it (below it
// when the two do not fit); each '\n' in `help` starts another line in that column.
std::string format_option(const std::string& name, const char* value, const char* help);

// One option of a program's command line. A program lists its options in one table, parses its
// command line with parse_options and prints its usage with options_usage, from the same entries.
template <typename Options>
struct Option {
  const char* name;   // as typed, "--voxel-size"
  const char* value;  // the argument's name in the usage ("M", "FILE"); nullptr: a flag
  const char* help;   // see format_option
  // Applies the option (a flag's gets ""); returns "" or the whole error message.
  std::string (*set)(Options& options, const std::string& value);
};

template <typename Options, std::size_t N>
std::string options_usage(const Option<Options> (&table)[N]) {
  std::string text;
  for (const Option<Options>& option : table) {
    text += format_option(option.name, option.value, option.help);
  }
  return text;
}

enum class Parsed { options, help, error };

// Applies argv[first], argv[first + 1], ... in order: `help` at the first "-h" or "--help";
// `error` with *error set at the first option the table lacks or whose value is missing
// (`unknown` + "'ARG' (see --help)") or that its setter refuses (the setter's message).
template <typename Options, std::size_t N>
Parsed parse_options(int argc, char** argv, int first, const Option<Options> (&table)[N],
                     const char* unknown, Options* options, std::string* error) {
  for (int i = first; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "-h" || arg == "--help") return Parsed::help;
    const Option<Options>* found = nullptr;
    for (const Option<Options>& option : table) {
      if (arg == option.name) found = &option;
    }
    if (found == nullptr || (found->value != nullptr && i + 1 >= argc)) {
      *error = std::string(unknown) + "'" + arg + "' (see --help)";
      return Parsed::error;
    }
    const std::string message = found->set(*options, found->value != nullptr ? argv[++i] : "");
    if (!message.empty()) {
      *error = message;
      return Parsed::error;
    }
  }
  return Parsed::options;
}

}  // namespace octofuse::cli
