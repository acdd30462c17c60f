#pragma once
// Fixed-capacity open-addressing hash from a block's Morton code to its pool index, so the
// integrator and the ray-caster find a block in O(1) without walking the tree. Linear probing,
// power-of-two table at most half full (capacity >= 2 x block capacity). erase() removes an
// entry by shifting the probe run behind it back (no tombstones), so a map that evicts blocks for
// ever keeps probe runs as short as a map that never did.

#include <cstddef>
#include <cstdint>

#include "octofuse/core/arena.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/map/voxel_block.hpp"

namespace octofuse {

class BlockHash {
 public:
  static constexpr std::uint64_t kEmpty = ~std::uint64_t{0};

  struct Entry {
    std::uint64_t morton = kEmpty;
    std::uint32_t index = kNoIndex;
    std::uint32_t padding = 0;
  };

  // Table size for `max_entries`: the next power of two >= 2 * max_entries.
  static std::size_t table_size(std::uint32_t max_entries) {
    std::size_t size = 16;
    while (size < 2 * static_cast<std::size_t>(max_entries)) size *= 2;
    return size;
  }

  template <typename Arena>
  Status reserve(Arena& arena, std::uint32_t max_entries) {
    const std::size_t size = table_size(max_entries);
    Result<Entry*> entries = arena.template allocate_array<Entry>(size, kArenaAlignment);
    if (!entries.ok()) return entries.status();
    entries_ = entries.value();
    mask_ = size - 1;
    max_entries_ = max_entries;
    size_ = 0;
    return ok_status();
  }

  void clear() {
    for (std::size_t i = 0; i <= mask_ && entries_ != nullptr; ++i) entries_[i] = Entry();
    size_ = 0;
  }

  // Pool index for `morton`, or kNoIndex.
  std::uint32_t find(std::uint64_t morton) const {
    std::size_t slot = hash(morton) & mask_;
    while (true) {
      const Entry& e = entries_[slot];
      if (e.morton == morton) return e.index;
      if (e.morton == kEmpty) return kNoIndex;
      slot = (slot + 1) & mask_;
    }
  }

  // Starts loading the slot `morton` hashes to (the table is large: lookups of scattered keys
  // miss the cache).
  void prefetch(std::uint64_t morton) const { __builtin_prefetch(&entries_[hash(morton) & mask_]); }

  // Inserts a new key (the caller has checked it is absent); resource_exhausted when full.
  Status insert(std::uint64_t morton, std::uint32_t index) {
    if (size_ >= max_entries_) return StatusCode::resource_exhausted;
    std::size_t slot = hash(morton) & mask_;
    while (entries_[slot].morton != kEmpty) slot = (slot + 1) & mask_;
    entries_[slot].morton = morton;
    entries_[slot].index = index;
    ++size_;
    return ok_status();
  }

  // Removes `morton`: true, or false when absent (nothing changes).
  bool erase(std::uint64_t morton) {
    std::size_t hole = hash(morton) & mask_;
    while (entries_[hole].morton != morton) {
      if (entries_[hole].morton == kEmpty) return false;
      hole = (hole + 1) & mask_;
    }
    // Backward shift: an entry after the hole moves into it unless its home slot lies cyclically
    // in (hole, slot], where a lookup would then stop at the hole before reaching it.
    std::size_t slot = hole;
    while (true) {
      slot = (slot + 1) & mask_;
      if (entries_[slot].morton == kEmpty) break;
      const std::size_t home = hash(entries_[slot].morton) & mask_;
      const bool stays =
          hole <= slot ? (hole < home && home <= slot) : (hole < home || home <= slot);
      if (stays) continue;
      entries_[hole] = entries_[slot];
      hole = slot;
    }
    entries_[hole] = Entry();
    --size_;
    return true;
  }

  // Points an existing key at a new pool index (a block moved by compaction): true, or false
  // when absent.
  bool set_index(std::uint64_t morton, std::uint32_t index) {
    std::size_t slot = hash(morton) & mask_;
    while (entries_[slot].morton != morton) {
      if (entries_[slot].morton == kEmpty) return false;
      slot = (slot + 1) & mask_;
    }
    entries_[slot].index = index;
    return true;
  }

  std::uint32_t size() const { return size_; }
  std::size_t table_entries() const { return mask_ + 1; }

 private:
  static std::size_t hash(std::uint64_t morton) {
    // Fibonacci hashing; Morton codes of neighbours differ in low bits, spread them.
    return static_cast<std::size_t>((morton * 0x9E3779B97F4A7C15ull) >> 20);
  }

  Entry* entries_ = nullptr;
  std::size_t mask_ = 0;
  std::uint32_t max_entries_ = 0;
  std::uint32_t size_ = 0;
};

}  // namespace octofuse
