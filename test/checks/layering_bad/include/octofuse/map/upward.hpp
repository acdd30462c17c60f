#pragma once
// For the layering check's own test: map reaching up into pipeline, which the check must refuse.
#include "octofuse/pipeline/pipeline.hpp"
