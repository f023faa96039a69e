"""Track: design alignment, irregularity synthesis, rail geometry and track-geometry products."""
