// The append-only block store: the newest record of a key wins across reopens, a file cut at any
// byte or damaged in its tail reopens with every whole record (and a warning), another map's store
// is refused, and a writer killed with SIGKILL at random instants loses nothing it had written.

#include "octofuse/ports/host/block_store_file.hpp"

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <catch2/catch.hpp>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "octofuse/map/keys.hpp"
#include "support/test_dir.hpp"

namespace octofuse {
namespace {

const std::uint8_t kGeometry[4] = {1, 2, 3, 4};

// A record's bytes, a function of its key and version (sizes vary with the key).
std::vector<std::uint8_t> record_of(std::uint64_t key, int version) {
  std::vector<std::uint8_t> r(40 + key % 97);
  for (std::size_t i = 0; i < r.size(); ++i) {
    r[i] = static_cast<std::uint8_t>(key * 31 + i * 7 + static_cast<std::size_t>(version) * 13);
  }
  return r;
}

std::uint64_t key_of(int i) {
  return morton_encode(Eigen::Vector3i(i % 7, (i / 7) % 5, i / 35));
}

Status open_store(host::BlockStoreFile& store, const std::string& path, ErrorText* warning,
                  const std::uint8_t* geometry = kGeometry) {
  ErrorText error;
  const Status s = store.open(path.c_str(), geometry, sizeof(kGeometry), &error, warning);
  INFO(error.c_str());
  return s;
}

bool holds(host::BlockStoreFile& store, std::uint64_t key, int version) {
  std::vector<std::uint8_t> got(4096);
  const Result<std::size_t> size = store.read(key, got.data(), got.size());
  if (!size.ok()) return false;
  got.resize(size.value());
  return got == record_of(key, version);
}

TEST_CASE("the block store keeps the newest record of each key across reopens") {
  const std::string dir = test::make_test_dir("block-store");
  const std::string path = dir + "/store";
  {
    host::BlockStoreFile store;
    ErrorText warning;
    REQUIRE(open_store(store, path, &warning).ok());
    REQUIRE(warning.empty());
    for (int i = 0; i < 50; ++i) {
      const std::vector<std::uint8_t> r = record_of(key_of(i), 0);
      REQUIRE(store.put(key_of(i), r.data(), r.size()).ok());
    }
    for (int i = 0; i < 50; i += 2) {  // newer versions of half of them
      const std::vector<std::uint8_t> r = record_of(key_of(i), 1);
      REQUIRE(store.put(key_of(i), r.data(), r.size()).ok());
    }
    REQUIRE(store.sync().ok());
    REQUIRE(store.stats().keys == 50u);
    REQUIRE(store.stats().entries == 75u);
    // find_in_box: keys in the box, increasing; taken ones are in memory and skipped.
    std::vector<std::uint64_t> keys(100);
    const std::size_t n = store.find_in_box(Eigen::Vector3i(0, 0, 0), Eigen::Vector3i(2, 4, 0),
                                            keys.data(), keys.size());
    REQUIRE(n == 15u);  // x 0..2, y 0..4, z 0
    for (std::size_t i = 1; i < n; ++i) REQUIRE(keys[i - 1] < keys[i]);
    std::vector<std::uint8_t> buffer(4096);
    REQUIRE(store.take(keys[0], buffer.data(), buffer.size()).ok());
    REQUIRE(store.in_memory(keys[0]));
    REQUIRE(store.find_in_box(Eigen::Vector3i(0, 0, 0), Eigen::Vector3i(2, 4, 0), keys.data(),
                              keys.size()) == 14u);
    store.release(keys[0]);
    REQUIRE_FALSE(store.in_memory(keys[0]));
    REQUIRE(store.take(morton_encode(Eigen::Vector3i(99, 0, 0)), buffer.data(), buffer.size())
                .status()
                .code() == StatusCode::out_of_range);
  }
  host::BlockStoreFile again;
  ErrorText warning;
  REQUIRE(open_store(again, path, &warning).ok());
  REQUIRE(warning.empty());
  REQUIRE(again.stats().keys == 50u);
  for (int i = 0; i < 50; ++i) REQUIRE(holds(again, key_of(i), i % 2 == 0 ? 1 : 0));
  again.close();
  // Another map's store is refused, and so is a file that is not a store.
  const std::uint8_t other[4] = {1, 2, 3, 5};
  host::BlockStoreFile wrong;
  REQUIRE(open_store(wrong, path, &warning, other).code() == StatusCode::invalid_argument);
  test::write_text(dir + "/text", "not a store, just some text that is long enough");
  REQUIRE(open_store(wrong, dir + "/text", &warning).code() == StatusCode::invalid_argument);
}

TEST_CASE("a store cut at any byte or damaged in its tail reopens with every whole record") {
  const std::string dir = test::make_test_dir("block-store-cut");
  const std::string path = dir + "/store";
  std::vector<std::size_t> ends;  // file size after each put
  {
    host::BlockStoreFile store;
    REQUIRE(open_store(store, path, nullptr).ok());
    ends.push_back(store.stats().file_bytes);
    for (int i = 0; i < 6; ++i) {
      const std::vector<std::uint8_t> r = record_of(key_of(i), 0);
      REQUIRE(store.put(key_of(i), r.data(), r.size()).ok());
      ends.push_back(store.stats().file_bytes);
    }
  }
  const std::string whole = test::read_bytes(path);
  REQUIRE(whole.size() == ends.back());
  for (std::size_t cut = 0; cut <= whole.size(); ++cut) {
    CAPTURE(cut);
    test::write_text(path, whole.substr(0, cut));
    host::BlockStoreFile store;
    ErrorText warning;
    REQUIRE(open_store(store, path, &warning).ok());
    int whole_records = 0;
    while (whole_records + 1 < static_cast<int>(ends.size()) &&
           ends[static_cast<std::size_t>(whole_records) + 1] <= cut) {
      ++whole_records;
    }
    REQUIRE(store.stats().keys == static_cast<std::uint64_t>(whole_records));
    for (int i = 0; i < whole_records; ++i) REQUIRE(holds(store, key_of(i), 0));
    // An empty file is a new store; any other cut between entries is torn.
    const bool torn = cut != 0 && std::find(ends.begin(), ends.end(), cut) == ends.end();
    REQUIRE(warning.empty() == !torn);
    // The torn tail is gone: appending continues after the last whole record.
    if (cut >= ends[0]) {
      REQUIRE(store.stats().file_bytes == ends[static_cast<std::size_t>(whole_records)]);
      const std::vector<std::uint8_t> r = record_of(key_of(40), 0);
      REQUIRE(store.put(key_of(40), r.data(), r.size()).ok());
      store.close();
      host::BlockStoreFile after;
      ErrorText none;
      REQUIRE(open_store(after, path, &none).ok());
      REQUIRE(none.empty());
      REQUIRE(holds(after, key_of(40), 0));
    }
  }
  // A flipped byte in the last record: that record goes, the others stay.
  std::string damaged = whole;
  damaged[ends[5] + 20] = static_cast<char>(damaged[ends[5] + 20] ^ 0x40);
  test::write_text(path, damaged);
  host::BlockStoreFile store;
  ErrorText warning;
  REQUIRE(open_store(store, path, &warning).ok());
  REQUIRE_FALSE(warning.empty());
  REQUIRE(store.stats().keys == 5u);
  for (int i = 0; i < 5; ++i) REQUIRE(holds(store, key_of(i), 0));
}

TEST_CASE(
    "compaction keeps the newest record of every key while puts go on, and shrinks the file") {
  const std::string dir = test::make_test_dir("block-store-compact");
  const std::string path = dir + "/store";
  host::BlockStoreFile store;
  ErrorText warning;
  REQUIRE(open_store(store, path, &warning).ok());
  store.set_compact_min_bytes(0);
  std::vector<int> newest(260, -1);
  auto put = [&](int k, int version) {
    const std::vector<std::uint8_t> r = record_of(key_of(k), version);
    REQUIRE(store.put(key_of(k), r.data(), r.size()).ok());
    newest[static_cast<std::size_t>(k)] = version;
  };
  for (int version = 0; version < 10; ++version) {
    for (int k = 0; k < 200; ++k) put(k, version);
  }
  // Two keys in memory: compaction must keep them out of find_in_box().
  std::vector<std::uint8_t> scratch(4096);
  REQUIRE(store.take(key_of(3), scratch.data(), scratch.size()).ok());
  REQUIRE(store.take(key_of(150), scratch.data(), scratch.size()).ok());
  const std::uint64_t before = store.stats().file_bytes;
  REQUIRE(before > 9 * store.stats().live_bytes);
  ErrorText error;
  std::mt19937 rng(3);
  int steps = 0;
  do {
    REQUIRE(store.compact_step(700, &error).ok());
    ++steps;
    // Puts between steps: keys already copied, keys not yet copied, new keys, taken keys.
    for (int i = 0; i < 3; ++i) {
      const int k = std::uniform_int_distribution<int>(0, 259)(rng);
      put(k, newest[static_cast<std::size_t>(k)] + 1);
    }
    REQUIRE(steps < 10000);
  } while (store.compacting());
  CAPTURE(steps);
  REQUIRE(steps > 10);  // done a little at a time
  const host::BlockStoreFileStats s = store.stats();
  REQUIRE(s.compactions == 1);
  REQUIRE(s.file_bytes < before / 3);
  REQUIRE(!test::file_exists(path + ".compact"));
  auto check_all = [&](host::BlockStoreFile& st) {
    for (int k = 0; k < 260; ++k) {
      if (newest[static_cast<std::size_t>(k)] < 0) continue;
      CAPTURE(k);
      REQUIRE(holds(st, key_of(k), newest[static_cast<std::size_t>(k)]));
    }
  };
  check_all(store);
  std::vector<std::uint64_t> keys(512);
  const std::size_t found = store.find_in_box(Eigen::Vector3i::Constant(-1000),
                                              Eigen::Vector3i::Constant(1000), keys.data(), 512);
  std::size_t stored = 0;
  for (int k = 0; k < 260; ++k) {
    if (newest[static_cast<std::size_t>(k)] >= 0 && !store.in_memory(key_of(k))) ++stored;
  }
  REQUIRE(found == stored);
  REQUIRE(stored < 260);  // the taken keys not put since stay out
  store.close();
  host::BlockStoreFile reopened;
  REQUIRE(open_store(reopened, path, &warning).ok());
  REQUIRE(warning.empty());
  check_all(reopened);
  // A fully compacted file holds the newest record of each key and nothing else.
  reopened.set_compact_min_bytes(0);
  while (reopened.stats().file_bytes <= 2 * reopened.stats().live_bytes) {
    const std::vector<std::uint8_t> r = record_of(key_of(9), newest[9] + 1);
    REQUIRE(reopened.put(key_of(9), r.data(), r.size()).ok());
    newest[9] += 1;
  }
  do {
    REQUIRE(reopened.compact_step(1u << 20, &error).ok());
  } while (reopened.compacting());
  REQUIRE(reopened.stats().file_bytes == reopened.stats().live_bytes);
  check_all(reopened);
}

TEST_CASE("a writer killed mid-compaction loses no record it had written") {
  const std::string dir = test::make_test_dir("block-store-compact-kill");
  std::mt19937 rng(11);
  for (int trial = 0; trial < 5; ++trial) {
    CAPTURE(trial);
    const std::string path = dir + "/store" + std::to_string(trial);
    int fds[2];
    REQUIRE(::pipe(fds) == 0);
    const pid_t child = ::fork();
    REQUIRE(child >= 0);
    if (child == 0) {
      ::close(fds[0]);
      host::BlockStoreFile store;
      if (!store.open(path.c_str(), kGeometry, sizeof(kGeometry), nullptr, nullptr).ok()) {
        ::_exit(2);
      }
      store.set_compact_min_bytes(0);
      for (int i = 0;; ++i) {
        const std::vector<std::uint8_t> r = record_of(key_of(i % 200), i / 200);
        if (!store.put(key_of(i % 200), r.data(), r.size()).ok()) ::_exit(3);
        if (!store.compact_step(300, nullptr).ok()) ::_exit(5);
        const std::int32_t done = i;
        if (::write(fds[1], &done, sizeof(done)) != sizeof(done)) ::_exit(4);
      }
    }
    ::close(fds[1]);
    const int wait_for = std::uniform_int_distribution<int>(500, 4000)(rng);
    std::int32_t last = -1;
    std::int32_t got = 0;
    while (last < wait_for && ::read(fds[0], &got, sizeof(got)) == sizeof(got)) last = got;
    ::kill(child, SIGKILL);
    int status = 0;
    ::waitpid(child, &status, 0);
    while (::read(fds[0], &got, sizeof(got)) == sizeof(got)) last = got;
    ::close(fds[0]);
    REQUIRE(WIFSIGNALED(status));
    host::BlockStoreFile store;
    ErrorText warning;
    REQUIRE(open_store(store, path, &warning).ok());
    REQUIRE(!test::file_exists(path + ".compact"));
    for (int k = 0; k < 200 && k <= last; ++k) {
      const int newest = (last - k) / 200;
      CAPTURE(k, newest, last);
      REQUIRE((holds(store, key_of(k), newest) || holds(store, key_of(k), newest + 1)));
    }
  }
}

TEST_CASE("a store's map geometry round-trips and out-of-range geometries are refused") {
  host::StoreGeometry g;
  g.voxel_type = MapVoxelType::multires16;
  g.voxel_size_m = 0.01f;
  g.voxel_depth = 10;
  g.origin_W = Eigen::Vector3f(-6.25f, 1.5f, -2.0f);
  std::uint8_t bytes[host::kStoreGeometryBytes];
  host::encode_store_geometry(g, bytes);
  // The voxel type, then five little-endian floats (0.01f is 0x3C23D70A).
  REQUIRE(bytes[0] == 3);
  REQUIRE(bytes[1] == 0x0A);
  REQUIRE(bytes[4] == 0x3C);
  host::StoreGeometry back;
  REQUIRE(host::decode_store_geometry(bytes, sizeof(bytes), &back));
  REQUIRE(back.voxel_type == g.voxel_type);
  REQUIRE(back.voxel_size_m == g.voxel_size_m);
  REQUIRE(back.voxel_depth == g.voxel_depth);
  REQUIRE(back.origin_W == g.origin_W);
  REQUIRE_FALSE(host::decode_store_geometry(bytes, sizeof(bytes) - 1, &back));
  auto refused = [&](host::StoreGeometry bad, std::uint8_t type = 3) {
    std::uint8_t b[host::kStoreGeometryBytes];
    host::encode_store_geometry(bad, b);
    b[0] = type;
    return !host::decode_store_geometry(b, sizeof(b), &back);
  };
  REQUIRE(refused(g, 0));
  REQUIRE(refused(g, 4));
  host::StoreGeometry bad = g;
  bad.voxel_size_m = std::nanf("");
  REQUIRE(refused(bad));
  bad = g;
  bad.voxel_size_m = 1e-9f;
  REQUIRE(refused(bad));
  bad = g;
  bad.voxel_depth = 40;
  REQUIRE(refused(bad));
  bad = g;
  bad.origin_W.x() = std::numeric_limits<float>::infinity();
  REQUIRE(refused(bad));
}

TEST_CASE("a short file that is not the start of a store is refused and left as it is") {
  const std::string dir = test::make_test_dir("block-store-short");
  const std::string notes = dir + "/notes.txt";
  test::write_text(notes, "keep\n");
  host::BlockStoreFile store;
  ErrorText warning;
  REQUIRE(open_store(store, notes, &warning).code() == StatusCode::invalid_argument);
  REQUIRE(test::read_bytes(notes) == "keep\n");
  // A store cut inside its header is the start of one: it starts empty, with a warning.
  const std::string path = dir + "/store";
  {
    host::BlockStoreFile whole;
    REQUIRE(open_store(whole, path, &warning).ok());
  }
  const std::string header = test::read_bytes(path);
  test::write_text(path, header.substr(0, 10));
  REQUIRE(open_store(store, path, &warning).ok());
  REQUIRE(!warning.empty());
  REQUIRE(test::read_bytes(path) == header);
}

TEST_CASE("a writer killed with SIGKILL at random instants loses no record it had written") {
  const std::string dir = test::make_test_dir("block-store-kill");
  std::mt19937 rng(7);
  for (int trial = 0; trial < 5; ++trial) {
    CAPTURE(trial);
    const std::string path = dir + "/store" + std::to_string(trial);
    int fds[2];
    REQUIRE(::pipe(fds) == 0);
    const pid_t child = ::fork();
    REQUIRE(child >= 0);
    if (child == 0) {
      ::close(fds[0]);
      host::BlockStoreFile store;
      if (!store.open(path.c_str(), kGeometry, sizeof(kGeometry), nullptr, nullptr).ok()) {
        ::_exit(2);
      }
      for (int i = 0;; ++i) {
        const int version = i / 200;
        const std::vector<std::uint8_t> r = record_of(key_of(i % 200), version);
        if (!store.put(key_of(i % 200), r.data(), r.size()).ok()) ::_exit(3);
        const std::int32_t done = i;
        if (::write(fds[1], &done, sizeof(done)) != sizeof(done)) ::_exit(4);
      }
    }
    ::close(fds[1]);
    // Let it write a random number of records, then kill it mid-stream.
    const int wait_for = std::uniform_int_distribution<int>(50, 900)(rng);
    std::int32_t last = -1;
    std::int32_t got = 0;
    while (last < wait_for && ::read(fds[0], &got, sizeof(got)) == sizeof(got)) last = got;
    ::kill(child, SIGKILL);
    int status = 0;
    ::waitpid(child, &status, 0);
    // Records written after `last` may or may not be there; drain what the pipe still holds.
    while (::read(fds[0], &got, sizeof(got)) == sizeof(got)) last = got;
    ::close(fds[0]);
    REQUIRE(WIFSIGNALED(status));
    host::BlockStoreFile store;
    ErrorText warning;
    REQUIRE(open_store(store, path, &warning).ok());
    // Every key written up to `last` holds its newest version up to `last`, or a newer one.
    for (int k = 0; k < 200 && k <= last; ++k) {
      const int newest = (last - k) / 200;  // version of key k's last put at or before `last`
      CAPTURE(k, newest, last);
      REQUIRE((holds(store, key_of(k), newest) || holds(store, key_of(k), newest + 1)));
    }
  }
}

}  // namespace
}  // namespace octofuse
