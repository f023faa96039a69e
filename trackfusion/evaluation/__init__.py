"""Evaluation: relative accuracy over distance scales (seed 002), repeatability, overlap statistics."""
