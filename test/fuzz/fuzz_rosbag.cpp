// The ROS 1 bag path: arbitrary bytes as a bag file through the ROS 1 reader (records, chunks,
// bz2 and lz4 decompression) and the bag source (topic choice, ROS 1 message decoding,
// TF chains, depth conversion) must give frames, a clear error or a warning, never a crash, a
// hang or a read past a buffer.
#include <cstddef>
#include <cstdint>

#include "fuzz_bag.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  octofuse::replay::BagConfig config;
  config.format = octofuse::replay::BagFormat::rosbag;
  config.limits.max_record_bytes = 256 << 10;  // the seeds' chunks are a few kB
  config.limits.max_chunk_bytes = 256 << 10;
  config.limits.max_channels = 16;
  return octofuse::fuzz::fuzz_bag_bytes(data, size, config, "fuzz_rosbag", "bag");
}
