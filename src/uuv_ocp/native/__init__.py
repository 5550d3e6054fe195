"""Native code: compiler discovery, content-addressed build cache, SIMD kernel, all-C IGWO."""
