#include "octofuse/map/octree.hpp"

namespace octofuse {

template class Octree<TsdfVoxel>;
template class Octree<MultiresVoxel>;

}  // namespace octofuse
