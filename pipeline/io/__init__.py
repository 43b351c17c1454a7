"""Input/output: mesh and sidecar loading and validation, atomic writes."""
