#pragma once
// Where evicted blocks go and come back from: a map larger than its memory. The library does no
// file I/O: it hands each evicted block over as one record (encode_block_record(), the map file's
// block record with its checksum) and asks for records back when the camera returns
// (restore_block_record()); a port keeps them (the host port's block_store_file.hpp: a crash-safe
// append-only file). The pipeline bounds the records written and read per frame
// (PipelineBudget::max_store_writes / max_store_reads).

#include <cstddef>
#include <cstdint>

#include <Eigen/Core>

#include "octofuse/core/error_text.hpp"
#include "octofuse/core/result.hpp"
#include "octofuse/core/status.hpp"
#include "octofuse/map/octree.hpp"

namespace octofuse {

// Keyed by the Morton code of a block's block coordinates (morton_encode(block.coords)).
class BlockStore {
 public:
  // Keeps `record` (size bytes) as the block's newest state, replacing any older one. ok, or the
  // store's error (the block's state is then lost; the pipeline counts it).
  virtual Status put(std::uint64_t block_morton, const std::uint8_t* record, std::size_t size) = 0;
  // Writes to `keys` (at most `capacity`) the keys of stored blocks not in memory whose block
  // coordinates lie in [lo, hi] (inclusive), in increasing key order; returns how many.
  virtual std::size_t find_in_box(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi,
                                  std::uint64_t* keys, std::size_t capacity) = 0;
  // Whether the block is stored and not in memory (what find_in_box() would list): a look-up, no
  // read.
  virtual bool holds(std::uint64_t block_morton) = 0;
  // Copies the block's newest record into `record` (capacity bytes): its size, or out_of_range (not
  // stored), data_loss (damaged on the medium) or the store's error. The block then counts as in
  // memory (find_in_box() skips it) until it is put again; its record stays, so a map file written
  // from the store after a crash still holds it.
  virtual Result<std::size_t> take(std::uint64_t block_morton, std::uint8_t* record,
                                   std::size_t capacity) = 0;
  // The block's record is its state again: the block taken last could not be restored (a pool
  // was full), it was evicted unchanged since take() (no need to write it again), or the map it
  // was in was cleared (Pipeline::reset()). It counts as stored again; a key not taken is ignored.
  virtual void release(std::uint64_t block_morton) = 0;

 protected:
  ~BlockStore() = default;
};

// Most bytes one block record of VoxelT takes.
template <typename VoxelT>
std::size_t block_record_max_bytes();

// Writes block `block` of `map` as one record into `out`: its size, or resource_exhausted when
// `capacity` is less than block_record_max_bytes<VoxelT>().
template <typename VoxelT>
Result<std::size_t> encode_block_record(const VoxelBlock<VoxelT>& block, std::uint8_t* out,
                                        std::size_t capacity);

// Allocates the block a record describes in `map` (creating its inner nodes) and restores its
// state: its pool index. Its summary is restored; the nodes above are not summarised (call
// propagate_summaries()). data_loss (the record is damaged or out of range, the map unchanged);
// out_of_range (outside the cube); failed_precondition when the block is in memory (mapped afresh);
// resource_exhausted when the block or node pool is full (the map unchanged). With the finest-level
// pool full, a block recorded with its finest level comes back without it, at scale 1 (brought up
// to date from scale 0 when needed), as Octree::release_finest() leaves a block.
template <typename VoxelT>
Result<std::uint32_t> restore_block_record(Octree<VoxelT>& map, const std::uint8_t* record,
                                           std::size_t size, ErrorText* error = nullptr);

// Whether `record` (a block record) holds a finest level; false for a damaged head or a
// single-res map.
template <typename VoxelT>
bool block_record_holds_finest(const std::uint8_t* record, std::size_t size);

// Gives block `index` of `map` (multires, integrated, at scale 1 or coarser, no finest level)
// the finest level of `record`: the same block's record from when it held one (as the pipeline's
// finest-level store keeps it: Pipeline::set_finest_store()). The block stays at its scale, as a
// block that kept its finest level while integrating coarser would be: its finest held level
// (scale 1 with its mid level, else 2, the record's scale 1 coming back too) is made the parent
// of the levels coming back, with what it learned since the record as the change the paper's
// down-propagation (eq. 5) applies when the block refines (the integrator does that when it
// next fuses the block at scale 0): each observed finest voxel then moves by its parent's change
// and gains the weight its parent gained; unobserved ones are interpolated from the parents.
// A block not fused since a record taken at scale 0 (its held level the same bits as the
// record's) comes back at scale 0, exactly as it was when it gave the level up.
// ok; data_loss (damaged record); invalid_argument (another block's record, or one without a
// finest level); failed_precondition (the block holds a finest level or is not integrated, or
// the map is single-res); out_of_range (no such block); resource_exhausted (the finest- or
// mid-level pool is full). Unless ok the map is unchanged.
template <typename VoxelT>
Status restore_finest_from_record(Octree<VoxelT>& map, std::uint32_t index,
                                  const std::uint8_t* record, std::size_t size, float y_max,
                                  ErrorText* error = nullptr);

}  // namespace octofuse
