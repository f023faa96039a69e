"""Gating of prism readings after a solve, and mis-lock detection.

A robotic total station that loses the trolley's prism may lock onto something else (another
reflector, a sign, a passing vehicle) and keep reporting it for seconds: a *run* of readings
that the fused trajectory cannot explain. After each solve every used reading's normalised
squared residual ``nis`` (3 degrees of freedom; polar precision) is compared with the gate.
Per station, in time order, the flagged readings are grouped: two flagged readings with at
most ``mislock_max_gap`` accepted readings between them belong to the same run. A run of
``mislock_min_run`` or more flagged readings is a **mis-lock**: every reading from its first to
its last is rejected (a mis-locked station may now and then report a point that happens to
pass the gate). Shorter runs are isolated **outliers**; only the flagged readings are rejected.

The gate is **progressive**: a round flags only readings whose ``nis`` exceeds both the gate and
``GROSS_FRACTION`` of the round's largest ``nis``. A reading of another reflector metres away
(``nis`` ~ 1e7) pulls the first solve, Huber loss or not, and makes good readings around it
fail the gate too; rejecting the gross readings first and solving again lets those readings
pass, so the rejected run is the mis-lock and not tens of seconds around it.

Readings that the step check (:mod:`.steps`) flagged before the fusion are rejected from the
start (:func:`prefused_rejections`); the gate then judges the others.
"""

from __future__ import annotations

import numpy as np

#: a round flags only readings above this fraction of its largest normalised residual
GROSS_FRACTION = 0.01


def classify_flags(flagged: np.ndarray, min_run: int, max_gap: int) -> tuple[np.ndarray, np.ndarray]:
    """For one station's readings in time order, flagged (N,) bool -> (rejected (N,) bool,
    in_mislock (N,) bool) following the module docstring's run logic."""
    pos = np.flatnonzero(flagged)
    rejected = flagged.copy()
    mislock = np.zeros(flagged.size, dtype=bool)
    if pos.size == 0:
        return rejected, mislock
    breaks = np.flatnonzero(np.diff(pos) - 1 > max_gap)
    starts = np.r_[0, breaks + 1]
    ends = np.r_[breaks, pos.size - 1]
    for a, b in zip(starts, ends):
        if b - a + 1 >= min_run:
            mislock[pos[a]:pos[b] + 1] = True
    return rejected | mislock, mislock


def gate_prisms(blocks, used: np.ndarray, prisms, settings) -> tuple[np.ndarray, list[dict]]:
    """Gate the used readings (indices into ``prisms``, a :class:`~trackfusion.registration.readings.PrismReadings`)
    whose factors are ``blocks`` (a ``LinearBlocks`` in the same order). ``settings``: the
    total-station factor settings (``gate_chi2``, ``mislock_min_run``, ``mislock_max_gap``).
    Returns (readings still used, [{"station", "t_s", "reason", "nis"}] newly rejected). The gate
    of this round is the larger of ``gate_chi2`` and ``GROSS_FRACTION`` of the largest ``nis``."""
    nis = np.sum(blocks.whitened() ** 2, axis=1)
    gate = max(settings.gate_chi2, GROSS_FRACTION * float(nis.max())) if nis.size else settings.gate_chi2
    keep = np.ones(used.size, dtype=bool)
    out: list[dict] = []
    sid = prisms.station[used]
    for j, name in enumerate(prisms.station_ids):
        mine = np.flatnonzero(sid == j)
        if mine.size == 0:
            continue
        rej, mis = classify_flags(nis[mine] > gate, settings.mislock_min_run,
                                  settings.mislock_max_gap)
        keep[mine[rej]] = False
        for i, m in zip(mine[rej], mis[rej]):
            out.append({"station": name, "t_s": float(prisms.t_s[used[i]]),
                        "reason": "mis_lock" if m else "outlier", "nis": float(nis[i]),
                        "detected_by": "gate"})
    return used[keep], out


def prefused_rejections(prisms) -> tuple[np.ndarray, list[dict]]:
    """The readings of ``prisms`` (:class:`~trackfusion.registration.readings.PrismReadings`) the fusion
    starts with, and ``[{"station", "t_s", "reason": "mis_lock", "nis": None, "detected_by":
    "step_check"}]`` for those flagged before it (``prisms.flagged``)."""
    used = prisms.usable()
    if prisms.flagged is None:
        return used, []
    out = [{"station": prisms.station_ids[int(prisms.station[i])], "t_s": float(prisms.t_s[i]), "reason": "mis_lock",
            "nis": None, "detected_by": "step_check"} for i in np.flatnonzero(prisms.flagged)]
    return used, out
