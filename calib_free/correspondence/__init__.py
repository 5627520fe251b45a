"""Correspondence and confidence: where the fixated patch came from (search, alignment, compiled kernels) and disparity along rows."""
