// The MCAP bag path: arbitrary bytes as a bag file through the container reader (records,
// chunks, zstd and lz4 decompression, CRCs) and the bag source (topic choice, CDR decoding,
// TF chains, depth conversion) must give frames, a clear error or a warning, never a crash, a
// hang or a read past a buffer.
#include <cstddef>
#include <cstdint>

#include "fuzz_bag.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  octofuse::replay::BagConfig config;
  config.limits.max_record_bytes = 1 << 20;
  config.limits.max_chunk_bytes = 1 << 20;
  config.limits.max_channels = 16;
  config.limits.max_schemas = 16;
  return octofuse::fuzz::fuzz_bag_bytes(data, size, config, "fuzz_mcap", "mcap");
}
