"""The run's outputs drawn from its tables alone — ``geometry.csv``, ``fused.mcap`` and the report's
table figures — written into the staging folder, in a forked child while the run evaluates.

``trackfusion run`` (``pipeline.write_outputs``) writes metrics.json, then these, then report.html
and metrics.json again. For a run smoothed in one batch they need nothing of the evaluation, so
:func:`start_table_outputs` writes them in a forked child (:mod:`trackfusion.forked`) as soon as
the track geometry is done, while the parent compares with the reference; the files and figures
are those written in turn, byte for byte (tests/test_forked_outputs.py). They go to temporary
names in the staging folder and are renamed there when complete; a failed child fails the run,
and the staging folder goes with everything in it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..forked import ForkedTask, ForkedTasks, can_fork


def write_table_outputs(stage: Path, table: dict[str, np.ndarray], origin, cfg, geometry=None, raw=None,
                        draw: bool = False, raw_copy: ForkedTask | None = None) -> dict[str, str]:
    """Write ``geometry.csv`` (+ sidecar, when ``geometry``) and ``fused.mcap`` (when
    ``cfg.outputs.fused_mcap``: the rows of ``table`` at most at ``sensors.fused.FUSED_POSE_RATE_HZ``,
    the rails, the raw log ``raw``, whose copy ``raw_copy`` began, :func:`start_raw_copy`) into
    ``stage``; with ``draw`` (and ``cfg.outputs.report``) returns the report's figures of ``table``
    and the geometry (:func:`~trackfusion.report.html.table_images`), else {}."""
    write_fused(stage, table, origin, cfg, geometry, raw, _begun(raw_copy))
    return write_geometry_and_figures(stage, table, origin, cfg, geometry, draw)


def write_fused(stage: Path, table: dict[str, np.ndarray], origin, cfg, geometry=None, raw=None,
                copy=None) -> None:
    """``fused.mcap`` of :func:`write_table_outputs` (nothing when ``cfg.outputs.fused_mcap`` is off);
    ``copy``: the first part of its copy of ``raw``, written already (:func:`start_raw_copy`)."""
    if cfg.outputs.fused_mcap:
        from ..sensors.fused import write_fused_mcap
        write_fused_mcap(stage / "fused.mcap", table, origin, raw=raw,
                         geometry=geometry.table if geometry is not None else None, copy=copy)


def start_raw_copy(background: ForkedTasks, stage: Path, raw, cfg) -> ForkedTask | None:
    """Begin fused.mcap's copy of the raw log ``raw`` (:func:`~trackfusion.sensors.fused.start_raw_copy`:
    most of fused.mcap's writing, and it needs nothing of the estimate) in a forked child of
    ``background``, on one thread at the lowest priority: the run smooths on the other CPU (its
    one-batch solve mostly uses one), and where both are busy the copy waits. None when fused.mcap
    is off or ``raw`` has no file to copy. (A run in chunks does not begin it: its child would keep
    the log's pages that the chunks free.) The task's result goes to :func:`write_table_outputs`
    or :func:`start_table_outputs`; the bytes are those of the copy made there."""
    if not cfg.outputs.fused_mcap or raw is None or raw.source is None:
        return None
    from ..sensors.fused import start_raw_copy as start
    return background.submit_idle("copying the raw log into fused.mcap", start, stage, raw, 1)


def _begun(raw_copy: ForkedTask | None):
    """The :class:`~trackfusion.sensors.mcap_log.CopyHead` of :func:`start_raw_copy`'s task (None: none)."""
    return raw_copy.result() if raw_copy is not None else None


def write_geometry_and_figures(stage: Path, table: dict[str, np.ndarray], origin, cfg, geometry=None,
                               draw: bool = False) -> dict[str, str]:
    """``geometry.csv`` and the figures of :func:`write_table_outputs`."""
    from ..sensors.fileio import read_sidecar, write_csv_table
    if geometry is not None:  # the track geometry: geometry.csv + geometry.json
        write_csv_table(stage / "geometry.csv", geometry.table, geometry.units, "n", origin.to_dict(),
                        fmt="%.12g", extra=geometry.sidecar())
    if not (draw and cfg.outputs.report):
        return {}
    from .html import table_images
    if geometry is None:
        return table_images(table)
    as_written = json.loads(json.dumps(geometry.metrics, allow_nan=False))  # the report reads metrics.json
    return table_images(table, geometry.table, as_written, read_sidecar(stage / "geometry.csv"))


def start_table_outputs(background: ForkedTasks, stage: Path, table: dict[str, np.ndarray], origin, cfg,
                        geometry=None, raw=None, raw_copy: ForkedTask | None = None) -> ForkedTask | None:
    """:func:`write_table_outputs` (with the figures) in forked children of ``background``: one
    writes fused.mcap (the rest of the raw log's copy ``raw_copy``, or all of it), the other
    geometry.csv and the figures; returns the second's task (result: the figures), or None when children cannot be
    forked (then the outputs are written in turn by ``pipeline.write_outputs``). ``background``
    waits for both."""
    if not can_fork():
        return None
    if cfg.outputs.report:
        from .figures import preload
        preload()  # imported once here, not in every child
    figures = background.submit("writing geometry.csv and the report figures", write_geometry_and_figures,
                                stage, table, origin, cfg, geometry, draw=True)
    if cfg.outputs.fused_mcap:  # after the figures' child: it may wait here for the copy's first part
        background.submit("writing fused.mcap", write_fused, stage, table, origin, cfg, geometry, raw,
                          _begun(raw_copy))
    return figures
