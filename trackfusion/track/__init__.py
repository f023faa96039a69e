"""Track: design alignment, irregularity spectra, rail geometry and track-geometry products (pure: no file I/O)."""
