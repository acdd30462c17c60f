#include "octofuse/map/octree.hpp"

namespace octofuse {

template class Octree<TsdfVoxel>;
template class Octree<MultiresVoxel>;
template class Octree<Multires16Voxel>;

}  // namespace octofuse
