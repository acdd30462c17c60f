#include "octofuse/ports/host/json_writer.hpp"

#include <catch2/catch.hpp>
#include <cmath>
#include <fstream>
#include <limits>

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
  CHECK(std::string(json.c_str()) == "[null,null,0.10000000000000001,18446744073709551615]");
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
