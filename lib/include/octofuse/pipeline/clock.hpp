#pragma once
// Clock lives in core (the worker team reads it too); this header keeps the pipeline's include.

#include "octofuse/core/clock.hpp"
