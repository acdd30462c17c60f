// Map files that must not load: truncated, bit-flipped, out-of-range, foreign, newer and
// mismatched files are reported with a Status and leave the map empty rather than half-loaded.

#include "octofuse/map/map_io.hpp"

#include <catch2/catch.hpp>

#include "unit/map/map_io_support.hpp"

namespace octofuse {
namespace {

TEST_CASE("crc32 matches the IEEE check value and continues across calls") {
  const char* text = "123456789";
  const auto* bytes = reinterpret_cast<const std::uint8_t*>(text);
  CHECK(crc32(bytes, 9) == 0xCBF43926u);
  CHECK(crc32(bytes + 4, 5, crc32(bytes, 4)) == 0xCBF43926u);
  CHECK(crc32(bytes, 0) == 0u);
}

TEST_CASE("crc32 equals the bitwise definition at every length and split") {
  // The polynomial applied bit by bit, as the standard defines it.
  auto reference = [](const std::uint8_t* bytes, std::size_t count) {
    std::uint32_t crc = 0xFFFFFFFFu;
    for (std::size_t i = 0; i < count; ++i) {
      crc ^= bytes[i];
      for (int k = 0; k < 8; ++k) crc = (crc & 1u) != 0 ? 0xEDB88320u ^ (crc >> 1) : crc >> 1;
    }
    return ~crc;
  };
  std::uint8_t bytes[300];
  std::uint32_t state = 12345u;
  for (std::uint8_t& b : bytes) {
    state = state * 1664525u + 1013904223u;
    b = static_cast<std::uint8_t>(state >> 24);
  }
  for (std::size_t count = 0; count <= sizeof(bytes); ++count) {
    CAPTURE(count);
    const std::uint32_t expected = reference(bytes, count);
    REQUIRE(crc32(bytes, count) == expected);
    // Any split, and any alignment of the start.
    const std::size_t split = count / 3;
    REQUIRE(crc32(bytes + split, count - split, crc32(bytes, split)) == expected);
  }
}

TEST_CASE("a 16-bit map file says so and is refused by float maps, and they by it",
          "[multires16]") {
  const Frames frames(3);
  Mapper<Multires16Voxel> q16(config_for<Multires16Voxel>());
  q16.run(frames, 0, frames.count());
  Mapper<MultiresVoxel> f32(config_for<MultiresVoxel>());
  f32.run(frames, 0, frames.count());
  const std::vector<std::uint8_t> file16 = save(q16.pipeline.map(), 3);
  const std::vector<std::uint8_t> file32 = save(f32.pipeline.map(), 3);
  REQUIRE(q16.pipeline.map().block_count() == f32.pipeline.map().block_count());
  CHECK(file16[12] == 3);  // the header's voxel type byte
  {
    MemorySource source(file16.data(), file16.size());
    const Result<MapFileHeader> header = read_map_header(source);
    REQUIRE(header.ok());
    CHECK(header.value().voxel_type == MapVoxelType::multires16);
    CHECK(std::string(map_voxel_type_name(header.value().voxel_type)) == "multires16");
  }
  // Half the voxel bytes: each block record holds 585 or 73 voxels of 8 bytes instead of 16.
  const std::vector<std::size_t> r16 = record_offsets(file16, true, 8);
  const std::vector<std::size_t> r32 = record_offsets(file32, true, 16);
  REQUIRE(r16.back() == file16.size());
  REQUIRE(r32.back() == file32.size());
  const std::uint32_t nodes = get_u32(file16, kNodeCountAt);
  const std::uint32_t blocks = get_u32(file16, kBlockCountAt);
  std::size_t voxels = 0;
  for (std::uint32_t i = 0; i < blocks; ++i) {
    const std::size_t record = r16[2 + nodes + i] - r16[1 + nodes + i];
    voxels += (record - 37) / 8;  // tag, key, state, summary and crc take 37 bytes
  }
  CHECK(voxels > 73 * blocks);  // some blocks hold a finest level
  CHECK(file32.size() - file16.size() == 8 * voxels);
  ErrorText error;
  BareMap<MultiresVoxel> float_map(config_for<MultiresVoxel>().map);
  CHECK(load_bytes(file16, float_map.map, &error).code() == StatusCode::invalid_argument);
  CHECK(std::string(error.c_str()).find("holds a multires16 map, this one is multires") !=
        std::string::npos);
  CHECK(empty(float_map.map));
  BareMap<TsdfVoxel> single(config_for<TsdfVoxel>().map);
  CHECK(load_bytes(file16, single.map, &error).code() == StatusCode::invalid_argument);
  CHECK(empty(single.map));
  BareMap<Multires16Voxel> compact(config_for<Multires16Voxel>().map);
  CHECK(load_bytes(file32, compact.map, &error).code() == StatusCode::invalid_argument);
  CHECK(std::string(error.c_str()).find("holds a multires map, this one is multires16") !=
        std::string::npos);
  CHECK(empty(compact.map));
  // The right map takes it.
  REQUIRE(load_bytes(file16, compact.map, &error).ok());
  CHECK(save(compact.map, 3) == file16);
}

TEST_CASE("a 16-bit TSDF step outside [-1, 1] in a file is data_loss", "[multires16]") {
  Mapper<Multires16Voxel> mapper(config_for<Multires16Voxel>());
  mapper.run(Frames(2), 0, 2);
  const std::vector<std::uint8_t> file = save(mapper.pipeline.map(), 2);
  const std::vector<std::size_t> records = record_offsets(file, true, 8);
  const std::uint32_t nodes = get_u32(file, kNodeCountAt);
  // The first block record: its first voxel's x (after the 33 bytes of key, state and summary).
  const std::size_t begin = records[1 + nodes];
  const std::size_t end = records[2 + nodes];
  REQUIRE(file[begin] == 'B');
  BareMap<Multires16Voxel> target(config_for<Multires16Voxel>().map);
  ErrorText error;
  for (const std::uint16_t bad_step : {std::uint16_t{16385}, std::uint16_t{0x8000}}) {
    CAPTURE(bad_step);
    std::vector<std::uint8_t> bad = file;
    bad[begin + 33] = static_cast<std::uint8_t>(bad_step);
    bad[begin + 34] = static_cast<std::uint8_t>(bad_step >> 8);
    reseal(bad, begin, end);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    CHECK(std::string(error.c_str()).find("out of range") != std::string::npos);
    CHECK(empty(target.map));
  }
  // The largest valid steps load.
  std::vector<std::uint8_t> edge = file;
  edge[begin + 33] = 0x00;
  edge[begin + 34] = 0xC0;  // -16384
  reseal(edge, begin, end);
  CHECK(load_bytes(edge, target.map, &error).ok());
}

TEST_CASE("truncation anywhere is data_loss and leaves the map empty") {
  const PipelineConfig config = corruption_config();
  Mapper<MultiresVoxel> mapper(config);
  mapper.run(Frames(2), 0, 2);
  INFO(mapper.pipeline.map().memory().finest_used << " of " << mapper.pipeline.map().block_count());
  REQUIRE(mapper.pipeline.map().memory().finest_used > 0);
  REQUIRE(mapper.pipeline.map().memory().finest_used < mapper.pipeline.map().block_count());
  const std::vector<std::uint8_t> file = save(mapper.pipeline.map());
  const std::vector<std::size_t> records = record_offsets(file, true);
  REQUIRE(records.back() == file.size());

  // At and around every record boundary, every byte of the header and first nodes, and a
  // stride through the block records.
  std::vector<std::size_t> cuts;
  for (std::size_t r : records) {
    for (std::size_t d : {std::size_t{0}, std::size_t{1}, std::size_t{3}, std::size_t{4}}) {
      if (r >= d) cuts.push_back(r - d);
      cuts.push_back(r + d);
    }
  }
  for (std::size_t i = 0; i < 200; ++i) cuts.push_back(i);
  for (std::size_t i = 0; i < file.size(); i += 211) cuts.push_back(i);

  BareMap<MultiresVoxel> target(config.map);
  int tried = 0;
  for (std::size_t cut : cuts) {
    if (cut >= file.size()) continue;
    REQUIRE(load_bytes(file, target.map).ok());  // full beforehand: failure must clear it
    const std::vector<std::uint8_t> part(file.begin(), file.begin() + cut);
    ErrorText error;
    const Status s = load_bytes(part, target.map, &error);
    INFO("cut at " << cut << ": " << error.c_str());
    REQUIRE(s.code() == StatusCode::data_loss);
    REQUIRE(empty(target.map));
    REQUIRE(std::strstr(error.c_str(), "truncated") != nullptr);
    // The check a save runs on what it wrote refuses it the same way.
    MemorySource checked(part.data(), part.size());
    REQUIRE(check_map(checked).code() == StatusCode::data_loss);
    ++tried;
  }
  CHECK(tried > 300);
}

TEST_CASE("a flipped bit anywhere is caught and leaves the map empty") {
  const PipelineConfig config = corruption_config();
  Mapper<MultiresVoxel> mapper(config);
  mapper.run(Frames(2), 0, 2);
  const std::vector<std::uint8_t> file = save(mapper.pipeline.map());
  BareMap<MultiresVoxel> target(config.map);
  std::vector<std::size_t> positions;
  for (std::size_t r : record_offsets(file, true)) {
    for (std::size_t d = 0; d < 12; ++d) positions.push_back(r + d);
  }
  for (std::size_t i = 0; i < file.size(); i += 97) positions.push_back(i);
  for (std::size_t at : positions) {
    if (at >= file.size()) continue;
    for (int bit : {0, 7}) {
      std::vector<std::uint8_t> bad = file;
      bad[at] = static_cast<std::uint8_t>(bad[at] ^ (1u << bit));
      ErrorText error;
      const Status s = load_bytes(bad, target.map, &error);
      INFO("byte " << at << " bit " << bit << ": " << error.c_str());
      REQUIRE(!s.ok());
      REQUIRE(empty(target.map));
      if (at >= 12) REQUIRE(s.code() == StatusCode::data_loss);
      MemorySource checked(bad.data(), bad.size());
      REQUIRE(check_map(checked).code() == s.code());
    }
  }
}

TEST_CASE("header fields out of range are refused by name, on load and before a save") {
  MapFileHeader good;
  good.voxel_size_m = 0.01f;
  good.mu_m = 0.08f;
  good.voxel_depth = 10;
  good.node_count = 1;
  REQUIRE(validate_map_header(good).ok());
  struct Case {
    const char* what;
    void (*spoil)(MapFileHeader&);
  };
  const Case cases[] = {
      {"voxel size", [](MapFileHeader& h) { h.voxel_size_m = 1e-9f; }},
      {"voxel size", [](MapFileHeader& h) { h.voxel_size_m = std::nanf(""); }},
      {"voxel size", [](MapFileHeader& h) { h.voxel_size_m = 1e6f; }},
      {"mu", [](MapFileHeader& h) { h.mu_m = 0.0f; }},
      {"mu", [](MapFileHeader& h) { h.mu_m = std::numeric_limits<float>::infinity(); }},
      {"voxel depth", [](MapFileHeader& h) { h.voxel_depth = 30; }},
      {"origin", [](MapFileHeader& h) { h.origin_W.x() = 1e30f; }},
      {"origin", [](MapFileHeader& h) { h.origin_W.z() = std::nanf(""); }},
      {"frame count", [](MapFileHeader& h) { h.frames = ~std::uint64_t{0}; }},
      {"counts", [](MapFileHeader& h) { h.node_count = 0; }},
      {"free-space octants",
       [](MapFileHeader& h) {
         h.free_node_count = 1;
         h.free_margin_m = 0.01f;
         h.free_max_count = 8;
         h.free_octant_voxels = 128;
       }},
  };
  for (const Case& c : cases) {
    MapFileHeader h = good;
    c.spoil(h);
    ErrorText error;
    CHECK(validate_map_header(h, &error).code() == StatusCode::data_loss);
    INFO(error.c_str());
    CHECK(std::string(error.c_str()).find(c.what) != std::string::npos);
  }

  // A save whose header would be refused writes nothing and says why.
  const PipelineConfig config = config_for<MultiresVoxel>();
  Mapper<MultiresVoxel> mapper(config);
  mapper.run(Frames(1), 0, 1);
  MapSaveInfo info;
  info.mu_m = config.fusion.mu_m;
  info.frames = kMaxSavedFrames + 1;
  VectorSink sink;
  ErrorText error;
  CHECK(save_map(mapper.pipeline.map(), info, sink).code() == StatusCode::invalid_argument);
  CHECK(save_map(mapper.pipeline.map(), nullptr, info, sink, &error).code() ==
        StatusCode::invalid_argument);
  CHECK(std::string(error.c_str()).find("frame count") != std::string::npos);
  CHECK(sink.data.empty());
  // At the bound it saves, checks and loads.
  info.frames = kMaxSavedFrames;
  REQUIRE(save_map(mapper.pipeline.map(), nullptr, info, sink, &error).ok());
  MemorySource source(sink.data.data(), sink.data.size());
  CHECK(check_map(source, nullptr, &error).ok());
}

TEST_CASE("foreign, newer, other-type, mismatched and oversized files are told apart") {
  const PipelineConfig config = corruption_config();
  Mapper<MultiresVoxel> mapper(config);
  mapper.run(Frames(2), 0, 2);
  const std::vector<std::uint8_t> file = save(mapper.pipeline.map());
  const std::vector<std::size_t> records = record_offsets(file, true);
  const std::size_t header_end = records[1];
  BareMap<MultiresVoxel> target(config.map);
  ErrorText error;

  SECTION("wrong magic") {
    std::vector<std::uint8_t> bad = file;
    std::memcpy(bad.data(), "PLYFORMA", 8);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::invalid_argument);
    CHECK(std::string(error.c_str()).find("not an octofuse map") != std::string::npos);
    const std::vector<std::uint8_t> text = {'p', 'l', 'y', '\n'};
    CHECK(load_bytes(text, target.map, &error).code() == StatusCode::data_loss);
    CHECK(load_bytes(std::vector<std::uint8_t>(), target.map, &error).code() ==
          StatusCode::data_loss);
  }
  SECTION("a newer version, whatever follows") {
    std::vector<std::uint8_t> bad = file;
    put_u32(bad, 8, kMapFormatVersion + 1);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::out_of_range);
    CHECK(std::string(error.c_str()).find("newer") != std::string::npos);
    MemorySource source(bad.data(), bad.size());
    CHECK(read_map_header(source).status().code() == StatusCode::out_of_range);
  }
  SECTION("the other voxel type") {
    BareMap<TsdfVoxel> single(config.map);
    CHECK(load_bytes(file, single.map, &error).code() == StatusCode::invalid_argument);
    CHECK(std::string(error.c_str()).find("multires") != std::string::npos);
    CHECK(empty(single.map));
  }
  SECTION("an unknown voxel type") {
    std::vector<std::uint8_t> bad = file;
    bad[12] = 9;
    reseal(bad, 0, header_end);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
  }
  SECTION("a different geometry than the map's") {
    MapConfig other = config.map;
    other.origin_W.x() += 0.5f;
    BareMap<MultiresVoxel> shifted(other);
    CHECK(load_bytes(file, shifted.map, &error).code() == StatusCode::invalid_argument);
    other = config.map;
    other.voxel_depth = 8;
    BareMap<MultiresVoxel> deeper(other);
    CHECK(load_bytes(file, deeper.map, &error).code() == StatusCode::invalid_argument);
  }
  SECTION("pools too small for the file") {
    MapConfig small = config.map;
    small.block_capacity = mapper.pipeline.map().block_count() - 1;
    BareMap<MultiresVoxel> tiny(small);
    CHECK(load_bytes(file, tiny.map, &error).code() == StatusCode::resource_exhausted);
    CHECK(std::string(error.c_str()).find("needs") != std::string::npos);
    CHECK(empty(tiny.map));
  }
  SECTION("absurd counts") {
    for (std::size_t field : {kNodeCountAt, kBlockCountAt, kFinestCountAt, kFreeCountAt}) {
      std::vector<std::uint8_t> bad = file;
      put_u32(bad, field, 0xFFFFFFF0u);
      reseal(bad, 0, header_end);
      CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    }
    std::vector<std::uint8_t> no_root = file;
    put_u32(no_root, kNodeCountAt, 0);
    reseal(no_root, 0, header_end);
    CHECK(load_bytes(no_root, target.map, &error).code() == StatusCode::data_loss);
  }
  SECTION("counts that disagree with the records") {
    std::vector<std::uint8_t> bad = file;
    put_u32(bad, kBlockCountAt, mapper.pipeline.map().block_count() - 1);
    reseal(bad, 0, header_end);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    CHECK(empty(target.map));
  }
  SECTION("non-finite or out-of-range values, even with a valid checksum") {
    const std::size_t block = records[records.size() - 3];  // the last block record
    const std::size_t end = records[records.size() - 2];
    const float bad_values[] = {std::numeric_limits<float>::quiet_NaN(),
                                std::numeric_limits<float>::infinity(), 1.5f, -2.0f};
    for (float v : bad_values) {
      std::uint32_t bits;
      std::memcpy(&bits, &v, 4);
      std::vector<std::uint8_t> bad = file;
      put_u32(bad, block + 1 + 8 + 4 + 4 + 16, bits);  // the first voxel's TSDF
      reseal(bad, block, end);
      CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
      CHECK(std::string(error.c_str()).find("out of range") != std::string::npos);
      bad = file;
      put_u32(bad, records[1] + 10, bits);  // the root's summary
      reseal(bad, records[1], records[2]);
      CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    }
  }
  SECTION("bad keys and states, even with a valid checksum") {
    const std::size_t block = records[records.size() - 3];
    const std::size_t end = records[records.size() - 2];
    std::vector<std::uint8_t> bad = file;
    bad[block + 1] |= 1;  // not block-aligned
    reseal(bad, block, end);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    bad = file;
    std::memcpy(&bad[block + 1], &file[records[records.size() - 4] + 1], 8);  // a duplicate
    reseal(bad, block, end);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    bad = file;
    bad[block + 13] = 5;  // current scale 5
    reseal(bad, block, end);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    bad = file;
    bad[records[2] + 1] = 0;  // a second root
    reseal(bad, records[2], records[3]);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    CHECK(empty(target.map));
  }
  SECTION("bytes after the end record") {
    std::vector<std::uint8_t> bad = file;
    bad.push_back(0);
    CHECK(load_bytes(bad, target.map, &error).code() == StatusCode::data_loss);
    CHECK(std::string(error.c_str()).find("extra bytes") != std::string::npos);
    CHECK(empty(target.map));
  }
}

}  // namespace
}  // namespace octofuse
