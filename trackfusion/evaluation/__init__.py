"""Evaluation: relative accuracy over distance scales (seed 002), repeatability (seed 000),
overlap statistics (seed 003).

Modules: :mod:`.errors_series` (matching, along/lateral/vertical split, moving part,
distance grid), :mod:`.relative` (seed 002 eqs. 1-6, 10, 16), :mod:`.repeatability`,
:mod:`.overlap`, :mod:`.api` (``evaluate_files``, result objects); the figure is
:mod:`trackfusion.report.evaluation_plots`.
See ``docs/evaluation.md``.
"""
