#pragma once
// What the octree tests share: a small map configuration and a map reserved in its own memory.

#include "octofuse/map/octree.hpp"

#include <algorithm>
#include <cstring>
#include <random>
#include <vector>

#include <catch2/catch.hpp>

#include "octofuse/map/detail/mip.hpp"
#include "support/aligned_buffer.hpp"
#include "support/alloc_counter.hpp"

namespace octofuse {
namespace {

inline MapConfig small_config(std::uint32_t blocks = 64, std::uint32_t nodes = 256) {
  MapConfig config;
  config.voxel_size_m = 0.01f;
  config.voxel_depth = 8;  // 256 voxels, 2.56 m
  config.origin_W = Eigen::Vector3f(-1.28f, -1.28f, -1.28f);
  config.block_capacity = blocks;
  config.node_capacity = nodes;
  return config;
}

template <typename VoxelT>
struct MapFixture {
  explicit MapFixture(const MapConfig& config) : buffer(Octree<VoxelT>::bytes_required(config)) {
    REQUIRE(map.reserve(buffer.arena(), config).ok());
  }
  test::ArenaBuffer buffer;
  Octree<VoxelT> map;
};

}  // namespace
}  // namespace octofuse
