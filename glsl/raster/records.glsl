// The per-intersection gradient records (KREC floats per slot), written by
// the tile backward and summed by the reduce. Before inclusion define
// RECORDS_BINDING (and RECORDS_ACCESS: readonly / writeonly). By default the
// records are that storage binding, so they are capped by
// maxStorageBufferRange (128 MiB on lavapipe: 1.86M intersections of 3
// channels); the RECORDS_BDA variant (`// variant: RECORDS_BDA`) binds a
// buffer holding the records' device address instead and reaches them
// through it, so they can be as large as one allocation.
#ifndef TGS_RASTER_RECORDS_GLSL
#define TGS_RASTER_RECORDS_GLSL
#ifdef RECORDS_BDA
layout(buffer_reference, std430, buffer_reference_align = 4) RECORDS_ACCESS buffer RecordWords { float v[]; };
layout(std430, binding = RECORDS_BINDING) readonly buffer RecordsAddress { uvec2 records_address; };
#define RECORDS RecordWords(records_address).v
#else
layout(std430, binding = RECORDS_BINDING) RECORDS_ACCESS buffer Records { float records_[]; };
#define RECORDS records_
#endif
#endif
