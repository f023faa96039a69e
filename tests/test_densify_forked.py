"""The densification of a one-batch run in parts (fusion/densify_forked.py: this process and
forked children writing into shared rows) gives the same rows, bit for bit, as one densify()
call; the rows come back private; a failed part is raised with every child reaped; the parts
are cut at densify's blocks."""

from __future__ import annotations

import numpy as np
import pytest

from trackfusion.forked import ForkedTasks
from trackfusion.fusion import densify_forked as DF
from trackfusion.fusion.trajectory import KeyframeStates, densify
from trackfusion.rotations import so3_exp
from trackfusion.sensors.types import ImuData


def test_part_bounds_cut_at_blocks_and_cover_every_interval():
    assert DF.part_bounds(31617, 2) == [(0, 16000), (16000, 31617)]
    assert DF.part_bounds(31617, 1) == [(0, 31617)]
    assert DF.part_bounds(DF.MIN_INTERVALS_PER_WORKER - 1, 2) == [(0, DF.MIN_INTERVALS_PER_WORKER - 1)]
    for n, w in ((9000, 2), (20001, 3), (50000, 4)):
        b = DF.part_bounds(n, w)
        assert b[0][0] == 0 and b[-1][1] == n and len(b) == w
        assert all(x[1] == y[0] and x[1] % DF.BLOCK == 0 for x, y in zip(b[:-1], b[1:]))


@pytest.fixture(scope="module")
def keyframed():
    """A synthetic IMU (500 Hz, 10 s of turning and accelerating) and keyframe states 0.1 s apart
    (perturbed, so that forward and backward integrations differ and the blend matters)."""
    rng = np.random.default_rng(5)
    n = 5_001
    t = np.arange(n) / 500.0
    gyro = np.column_stack([1e-3 * np.sin(0.3 * t), 2e-3 * np.cos(0.2 * t), 0.01 * np.sin(0.05 * t)])
    accel = np.column_stack([0.2 * np.sin(0.1 * t), 0.05 * np.cos(0.3 * t), np.full(n, 9.8)])
    imu = ImuData(t, gyro + 1e-5 * rng.normal(size=(n, 3)), accel + 1e-3 * rng.normal(size=(n, 3)))
    key_idx = np.r_[np.arange(0, n - 1, 50), n - 1]
    K = key_idx.size
    R = so3_exp(1e-3 * rng.normal(size=(K, 3)))
    keys = KeyframeStates(key_idx, R, rng.normal(size=(K, 3)), rng.normal(size=(K, 3)), 1e-6 * rng.normal(size=(K, 3)),
                          1e-4 * rng.normal(size=(K, 3)), np.tile([0.0, 0.0, -9.79], (K, 1)))
    return imu, keys, np.array([0.0, 5e-5, 4e-5])


@pytest.fixture
def small_parts(monkeypatch):
    """Blocks of 20 intervals and parts of at least 30 (the 100 intervals of :func:`keyframed` in
    whole blocks), forking allowed; the tasks submitted to any ForkedTasks, in order."""
    monkeypatch.setattr(DF, "MIN_INTERVALS_PER_WORKER", 30)
    monkeypatch.setattr(DF, "BLOCK", 20)
    monkeypatch.setattr(DF, "can_fork", lambda n: True)
    submitted = []
    real_submit = ForkedTasks.submit

    def submit(self, *args, **kwargs):
        submitted.append(real_submit(self, *args, **kwargs))
        return submitted[-1]
    monkeypatch.setattr(ForkedTasks, "submit", submit)
    return submitted


def test_forked_parts_equal_one_densify_call(keyframed, small_parts, monkeypatch):
    """Two and three parts (this process one of them, children the others, writing into shared
    rows), and one call here where forking is not possible: the rows of one densify call."""
    assert DF.part_bounds(keyframed[1].key_idx.size - 1, 2) == [(0, 40), (40, 100)]
    whole = densify(*keyframed, block=20)
    for forked, workers, children in ((True, 2, 1), (True, 3, 2), (True, 1, 0), (False, 2, 0)):
        monkeypatch.setattr(DF, "can_fork", lambda n, forked=forked: forked)
        small_parts.clear()
        dense = DF.densify_forked(*keyframed, workers=workers)
        assert len(small_parts) == children
        for name in ("t_s", "R_nb", "pos_n", "vel_n"):
            got = getattr(dense, name)
            np.testing.assert_array_equal(got, getattr(whole, name))
            assert got.flags.owndata


def test_the_rows_are_private_once_returned(keyframed, small_parts):
    """The children wrote into shared memory; the returned rows are this process's own copy: a
    later forked child writing into them changes nothing here."""
    dense = DF.densify_forked(*keyframed, workers=2)
    before = dense.pos_n.copy()

    def scribble():
        dense.pos_n[:] = 0.0
    with ForkedTasks(always_fork=True) as tasks:
        tasks.submit("scribbling", scribble)
        tasks.wait()
    np.testing.assert_array_equal(dense.pos_n, before)


#: densify_forked's own part function (the tests below replace it)
REAL_PART_INTO = DF._part_into


def _failing_in(monkeypatch, failing: int, parts: int) -> None:
    """``DF._part_into`` raising for part ``failing`` of ``parts`` (0: this process's own)."""
    real_part = REAL_PART_INTO

    def part(out, imu, keys, omega_ie_n, bounds):
        if bounds[0] == DF.part_bounds(keys.key_idx.size - 1, parts)[failing][0]:
            raise ValueError(f"part {failing} failed")
        return real_part(out, imu, keys, omega_ie_n, bounds)
    monkeypatch.setattr(DF, "_part_into", part)


def test_a_failed_part_is_raised_and_the_other_child_reaped(keyframed, small_parts, monkeypatch):
    for failing in (1, 2):  # a child's part, or the last one
        _failing_in(monkeypatch, failing, 3)
        small_parts.clear()
        with pytest.raises(ValueError, match=f"part {failing} failed"):
            DF.densify_forked(*keyframed, workers=3)
        assert len(small_parts) == 2 and all(c.pid is None for c in small_parts)  # both waited for or killed


def test_a_failure_here_kills_the_children(keyframed, small_parts, monkeypatch):
    """This process's own part fails: the children are killed and reaped, the error raised."""
    _failing_in(monkeypatch, 0, 2)
    with pytest.raises(ValueError, match="part 0 failed"):
        DF.densify_forked(*keyframed, workers=2)
    assert len(small_parts) == 1 and small_parts[0].pid is None
