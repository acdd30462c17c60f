// The option tables the example programs parse their command lines with and print their usage
// from (cli.hpp).
#include <catch2/catch.hpp>
#include <string>
#include <vector>

#include "cli.hpp"

namespace octofuse::cli {
namespace {

struct Args {
  bool flag = false;
  long count = 0;
};

const Option<Args> kOptions[] = {
    {"--flag", nullptr, "a flag",
     [](Args& a, const std::string&) {
       a.flag = true;
       return std::string();
     }},
    {"--count", "N", "a count\nin two lines",
     [](Args& a, const std::string& v) {
       std::int64_t n = 0;
       if (!parse_int(v, 1, 10, n)) return std::string("--count needs a count in [1, 10]");
       a.count = static_cast<long>(n);
       return std::string();
     }},
};

Parsed parse(std::vector<std::string> words, Args* args, std::string* error) {
  std::vector<char*> argv;
  for (std::string& word : words) argv.push_back(word.data());
  return parse_options(static_cast<int>(argv.size()), argv.data(), 1, kOptions, "unknown option ",
                       args, error);
}

TEST_CASE("the usage comes from the option table, help in one column") {
  CHECK(options_usage(kOptions) ==
        "  --flag               a flag\n"
        "  --count N            a count\n"
        "                       in two lines\n");
  CHECK(format_option("--a-very-long-option", "VALUE", "x") ==
        "  --a-very-long-option VALUE   x\n");
}

TEST_CASE("options parse in order; unknown, incomplete and refused ones are errors") {
  Args args;
  std::string error;
  CHECK(parse({"prog", "--flag", "--count", "3"}, &args, &error) == Parsed::options);
  CHECK(args.flag);
  CHECK(args.count == 3);
  CHECK(parse({"prog", "--count", "3", "-h", "--bogus"}, &args, &error) == Parsed::help);
  CHECK(parse({"prog", "--bogus", "-h"}, &args, &error) == Parsed::error);
  CHECK(error == "unknown option '--bogus' (see --help)");
  CHECK(parse({"prog", "--count"}, &args, &error) == Parsed::error);
  CHECK(error == "unknown option '--count' (see --help)");
  CHECK(parse({"prog", "--count", "11"}, &args, &error) == Parsed::error);
  CHECK(error == "--count needs a count in [1, 10]");
}

}  // namespace
}  // namespace octofuse::cli
