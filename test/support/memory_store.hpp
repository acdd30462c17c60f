#pragma once
// A BlockStore in memory for tests: the newest record of each key, and which keys are taken.

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <map>
#include <vector>

#include "octofuse/map/block_store.hpp"

namespace octofuse {

// A BlockStore in memory: the newest record of each key.
class MemoryStore final : public BlockStore {
 public:
  Status put(std::uint64_t key, const std::uint8_t* record, std::size_t size) override {
    Entry& e = entries_[key];
    e.bytes.assign(record, record + size);
    e.in_memory = false;
    ++puts;
    return ok_status();
  }
  std::size_t find_in_box(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi, std::uint64_t* keys,
                          std::size_t capacity) override {
    std::size_t n = 0;
    for (const auto& [key, e] : entries_) {
      const Eigen::Vector3i c = morton_decode(key);
      if (n == capacity || e.in_memory) continue;
      if ((c.array() < lo.array()).any() || (c.array() > hi.array()).any()) continue;
      keys[n++] = key;
    }
    return n;
  }
  bool holds(std::uint64_t key) override {
    const auto it = entries_.find(key);
    return it != entries_.end() && !it->second.in_memory;
  }
  Result<std::size_t> take(std::uint64_t key, std::uint8_t* record, std::size_t capacity) override {
    const auto it = entries_.find(key);
    if (it == entries_.end()) return StatusCode::out_of_range;
    if (it->second.bytes.size() > capacity) return StatusCode::resource_exhausted;
    std::copy(it->second.bytes.begin(), it->second.bytes.end(), record);
    it->second.in_memory = true;
    return it->second.bytes.size();
  }
  void release(std::uint64_t key) override {
    const auto it = entries_.find(key);
    if (it == entries_.end()) return;  // never stored
    it->second.in_memory = false;
    ++releases;
  }
  const std::vector<std::uint8_t>* record(std::uint64_t key) const {
    const auto it = entries_.find(key);
    return it == entries_.end() ? nullptr : &it->second.bytes;
  }
  // Keys taken and not put or released since: blocks the store counts as in memory.
  std::size_t taken() const {
    std::size_t n = 0;
    for (const auto& entry : entries_) n += entry.second.in_memory ? 1 : 0;
    return n;
  }
  std::size_t puts = 0;
  std::size_t releases = 0;

 private:
  struct Entry {
    std::vector<std::uint8_t> bytes;
    bool in_memory = false;
  };
  std::map<std::uint64_t, Entry> entries_;
};

}  // namespace octofuse
