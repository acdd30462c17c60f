#include "octofuse/map/detail/block_hash.hpp"

#include <algorithm>
#include <cstdint>
#include <random>
#include <vector>

#include <catch2/catch.hpp>

#include "octofuse/map/keys.hpp"
#include "support/aligned_buffer.hpp"

namespace octofuse {
namespace {

struct HashFixture {
  explicit HashFixture(std::uint32_t max_entries)
      : buffer(BlockHash::table_size(max_entries) * sizeof(BlockHash::Entry) + kArenaAlignment) {
    REQUIRE(hash.reserve(buffer.arena(), max_entries).ok());
  }
  test::ArenaBuffer buffer;
  BlockHash hash;
};

// Every key in `present` maps to its index, every key in `absent` is missing.
void check_contents(const BlockHash& hash, const std::vector<std::uint64_t>& keys,
                    const std::vector<bool>& present) {
  std::uint32_t count = 0;
  for (std::size_t i = 0; i < keys.size(); ++i) {
    CAPTURE(i);
    if (present[i]) {
      REQUIRE(hash.find(keys[i]) == static_cast<std::uint32_t>(i));
      ++count;
    } else {
      REQUIRE(hash.find(keys[i]) == kNoIndex);
    }
  }
  REQUIRE(hash.size() == count);
}

TEST_CASE("erase keeps every other key findable, in any order and across the table's wrap",
          "[map][block_hash]") {
  // Neighbouring blocks (Morton codes of a dense 16^3 grid) plus scattered ones: long probe runs
  // and runs that wrap past the table's end both occur at half load.
  constexpr std::uint32_t kKeys = 4096 + 1024;
  std::vector<std::uint64_t> keys;
  for (int z = 0; z < 16; ++z) {
    for (int y = 0; y < 16; ++y) {
      for (int x = 0; x < 16; ++x) keys.push_back(morton_encode(Eigen::Vector3i(x, y, z)));
    }
  }
  std::mt19937_64 rng(17);
  while (keys.size() < kKeys) {
    const std::uint64_t k = morton_encode(Eigen::Vector3i(
        static_cast<int>(rng() % 100000), static_cast<int>(rng() % 100000), 16 + rng() % 1000));
    if (std::find(keys.begin(), keys.end(), k) == keys.end()) keys.push_back(k);
  }
  HashFixture f(kKeys);
  std::vector<bool> present(keys.size(), true);
  for (std::size_t i = 0; i < keys.size(); ++i) {
    REQUIRE(f.hash.insert(keys[i], static_cast<std::uint32_t>(i)).ok());
  }
  check_contents(f.hash, keys, present);

  std::vector<std::size_t> order(keys.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::shuffle(order.begin(), order.end(), rng);
  // Erase two thirds, checking everything after every 500.
  for (std::size_t n = 0; n < 2 * keys.size() / 3; ++n) {
    const std::size_t i = order[n];
    REQUIRE(f.hash.erase(keys[i]));
    present[i] = false;
    REQUIRE_FALSE(f.hash.erase(keys[i]));  // gone: a second erase changes nothing
    if (n % 500 == 0) check_contents(f.hash, keys, present);
  }
  check_contents(f.hash, keys, present);

  // Re-inserted keys are found again, and so is everything that stayed.
  for (std::size_t n = 0; n < keys.size() / 3; ++n) {
    const std::size_t i = order[n];
    REQUIRE(f.hash.insert(keys[i], static_cast<std::uint32_t>(i)).ok());
    present[i] = true;
  }
  check_contents(f.hash, keys, present);
}

TEST_CASE("erase in a full small table: every subset removed leaves the rest findable",
          "[map][block_hash]") {
  // 8 entries in a 16-slot table: a single cluster whatever the hash does; each of the 256
  // subsets is erased (in increasing key order) from a fresh table.
  constexpr std::uint32_t kKeys = 8;
  std::vector<std::uint64_t> keys;
  for (std::uint64_t k = 0; k < kKeys; ++k) keys.push_back(k * 7 + 3);
  for (std::uint32_t subset = 0; subset < (1u << kKeys); ++subset) {
    CAPTURE(subset);
    HashFixture f(kKeys);
    REQUIRE(f.hash.table_entries() == 16u);
    for (std::uint32_t i = 0; i < kKeys; ++i) REQUIRE(f.hash.insert(keys[i], i).ok());
    REQUIRE(f.hash.insert(1000, 99) == StatusCode::resource_exhausted);
    std::vector<bool> present(kKeys, true);
    for (std::uint32_t i = 0; i < kKeys; ++i) {
      if ((subset >> i) & 1u) {
        REQUIRE(f.hash.erase(keys[i]));
        present[i] = false;
      }
    }
    check_contents(f.hash, keys, present);
  }
}

TEST_CASE("set_index repoints a present key and refuses an absent one", "[map][block_hash]") {
  HashFixture f(4);
  REQUIRE(f.hash.insert(11, 0).ok());
  REQUIRE(f.hash.insert(12, 1).ok());
  REQUIRE(f.hash.set_index(12, 7));
  CHECK(f.hash.find(12) == 7u);
  CHECK(f.hash.find(11) == 0u);
  CHECK_FALSE(f.hash.set_index(13, 2));
  CHECK(f.hash.find(13) == kNoIndex);
  CHECK(f.hash.size() == 2u);
}

}  // namespace
}  // namespace octofuse
