"""Geometry: frames and units, safe repairs, sphere fits, segmentation, remeshing, projection, snapping."""
