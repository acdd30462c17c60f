#include "octofuse/ports/host/json_writer.hpp"

#include <catch2/catch.hpp>
#include <clocale>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <random>
#include <string>

#include "support/test_dir.hpp"

using octofuse::host::JsonWriter;

TEST_CASE("JSON writer nests objects and arrays with commas", "[host][json]") {
  JsonWriter json;
  json.begin_object();
  json.key("frames").value(3);
  json.key("ms").begin_array().value(1.5).value(2.0).value(std::int64_t{-4}).end_array();
  json.key("tracked").value(true);
  json.key("summary").begin_object().key("ate_m").null().end_object();
  json.key("empty").begin_array().end_array();
  json.end_object();
  CHECK(json.complete());
  CHECK(std::string(json.c_str()) ==
        R"({"frames":3,"ms":[1.5,2,-4],"tracked":true,"summary":{"ate_m":null},"empty":[]})");
}

TEST_CASE("JSON writer escapes strings", "[host][json]") {
  JsonWriter json;
  json.begin_object();
  json.key("k\"ey").value("a\"b\\c\nd\te\x01\x1f/\xc3\xa9");
  json.key("ctl").value("\b\f\r");
  json.end_object();
  CHECK(std::string(json.c_str()) ==
        "{\"k\\\"ey\":\"a\\\"b\\\\c\\nd\\te\\u0001\\u001f/\xc3\xa9\",\"ctl\":\"\\b\\f\\r\"}");
  CHECK(json.size() == std::string(json.c_str()).size());
}

TEST_CASE("JSON writer writes non-finite numbers as null and doubles exactly", "[host][json]") {
  JsonWriter json;
  json.begin_array()
      .value(std::numeric_limits<double>::quiet_NaN())
      .value(std::numeric_limits<double>::infinity())
      .value(0.1)
      .value(std::uint64_t{18446744073709551615ull})
      .end_array();
  CHECK(std::string(json.c_str()) == "[null,null,0.1,18446744073709551615]");
}

TEST_CASE("JSON writer refuses to write an incomplete document", "[host][json]") {
  const std::string dir = octofuse::test::make_test_dir("json");
  JsonWriter json;
  json.begin_object();
  octofuse::ErrorText error;
  const std::string path = dir + "/stats.json";
  CHECK(json.write_file(path.c_str(), &error) == octofuse::StatusCode::failed_precondition);
  json.end_object();
  REQUIRE(json.write_file(path.c_str(), &error).ok());
  std::ifstream in(path);
  std::string text;
  std::getline(in, text);
  CHECK(text == "{}");
}

TEST_CASE("JSON writer replaces a file whole, through a temporary it removes", "[host][json]") {
  const std::string dir = octofuse::test::make_test_dir("json-atomic");
  const std::string path = dir + "/stats.json";
  octofuse::ErrorText error;
  JsonWriter first;
  first.begin_object().key("run").value(1).end_object();
  REQUIRE(first.write_file(path.c_str(), &error).ok());
  JsonWriter second;
  second.begin_object().key("run").value(2).end_object();
  REQUIRE(second.write_file(path.c_str(), &error).ok());
  std::ifstream in(path);
  std::string text;
  std::getline(in, text);
  CHECK(text == "{\"run\":2}");
  CHECK(!std::ifstream(path + ".tmp").good());
  const std::string missing = dir + "/no-such-folder/stats.json";
  CHECK(second.write_file(missing.c_str(), &error) == octofuse::StatusCode::unavailable);
  CHECK(std::string(error.c_str()).find("no-such-folder") != std::string::npos);
}

namespace {

std::string one_number(double number) {
  JsonWriter json;
  json.begin_array().value(number).end_array();
  const std::string text = json.c_str();
  return text.substr(1, text.size() - 2);
}

}  // namespace

TEST_CASE("JSON writer writes the shortest text that reads back as the same double",
          "[host][json]") {
  CHECK(one_number(7.527) == "7.527");
  CHECK(one_number(126.0) == "126");
  CHECK(one_number(-0.25) == "-0.25");
  CHECK(one_number(1e300) == "1e+300");
  CHECK(one_number(5e-324) == "5e-324");
  CHECK(one_number(0.1 + 0.2) == "0.30000000000000004");  // one digit fewer would be 0.3
  std::mt19937_64 random(7);
  for (int i = 0; i < 20000; ++i) {
    double number = 0.0;
    do {
      const std::uint64_t bits = random();
      static_assert(sizeof(bits) == sizeof(number), "64-bit double");
      std::memcpy(&number, &bits, sizeof(number));
    } while (!std::isfinite(number));
    const std::string text = one_number(number);
    REQUIRE(std::strtod(text.c_str(), nullptr) == number);
    CHECK(text.size() <= 24);
  }
}

TEST_CASE("JSON numbers keep a '.' under a locale with a decimal comma", "[host][json]") {
  // de_DE if the system has it; otherwise compiled from the system's locale sources into the
  // test folder. Without either there is no comma locale to try, and the test says so.
  const char* const names[] = {"de_DE.UTF-8", "de_DE.utf8", "de_DE", "fr_FR.UTF-8"};
  bool comma = false;
  for (const char* name : names) comma = comma || std::setlocale(LC_NUMERIC, name) != nullptr;
  if (!comma) {
    const std::string dir = octofuse::test::make_test_dir("locale");
    const std::string command =
        "localedef -i de_DE -f UTF-8 " + dir + "/de_DE.UTF-8 >/dev/null 2>&1";
    if (!dir.empty() && std::system(command.c_str()) == 0) {
      ::setenv("LOCPATH", dir.c_str(), 1);
      comma = std::setlocale(LC_NUMERIC, "de_DE.UTF-8") != nullptr;
      ::unsetenv("LOCPATH");
    }
  }
  if (!comma) {
    WARN("no locale with a decimal comma on this system: checked the C locale only");
  } else {
    char printed[16];
    std::snprintf(printed, sizeof(printed), "%.3f", 7.527);
    CHECK(std::string(printed) == "7,527");  // the locale is in effect for printf
  }
  JsonWriter json;
  json.begin_object().key("ms").value(7.527).key("n").value(1e-7).end_object();
  std::setlocale(LC_NUMERIC, "C");
  CHECK(std::string(json.c_str()) == "{\"ms\":7.527,\"n\":1e-07}");
}
