"""The densification of a one-batch run in forked workers (fusion/densify_forked.py) gives the
same rows, bit for bit, as one densify() call (in two children, in one, or here); and the parts
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


def test_forked_parts_equal_one_densify_call(keyframed, monkeypatch):
    monkeypatch.setattr(DF, "MIN_INTERVALS_PER_WORKER", 40)  # 100 intervals: 2 parts of whole blocks
    monkeypatch.setattr(DF, "BLOCK", 20)
    assert DF.part_bounds(keyframed[1].key_idx.size - 1, 2) == [(0, 40), (40, 100)]
    whole = densify(*keyframed, block=20)
    for forked, workers, children in ((True, 2, 2), (True, 1, 1), (False, 2, 0)):  # forked parts, or one call here
        monkeypatch.setattr(DF, "can_fork", lambda n, forked=forked: forked)
        with ForkedTasks(always_fork=True) as tasks:
            parts = DF.start_densify_forked(tasks, *keyframed, workers=workers).result()
            assert len(tasks.tasks) == children
        for name in ("t_s", "R_nb", "pos_n", "vel_n"):
            np.testing.assert_array_equal(getattr(parts, name), getattr(whole, name))


def test_started_densification_uses_the_states_at_its_start(keyframed, monkeypatch):
    """start_densify_forked returns while its children work: this process may go on (here it
    overwrites the states it handed over) and result() still gives the rows of the states at
    the start, bit for bit."""
    monkeypatch.setattr(DF, "MIN_INTERVALS_PER_WORKER", 40)
    monkeypatch.setattr(DF, "BLOCK", 20)
    monkeypatch.setattr(DF, "can_fork", lambda n: True)
    whole = densify(*keyframed, block=20)
    imu, shared, omega_ie_n = keyframed
    keys = KeyframeStates(*(a.copy() for a in vars(shared).values()))
    with ForkedTasks(always_fork=True) as tasks:
        job = DF.start_densify_forked(tasks, imu, keys, omega_ie_n, workers=2)
        assert len(tasks.tasks) == 2 and all(t.pid is not None for t in tasks.tasks)  # two children at work
        keys.R_nb[:] = np.eye(3)  # R_nb, and pos_n, overwritten after the start
        keys.pos_n[:] = 0.0
        dense = job.result()
    for name in ("t_s", "R_nb", "pos_n", "vel_n"):
        np.testing.assert_array_equal(getattr(dense, name), getattr(whole, name))


def test_a_failed_part_is_raised_and_the_other_child_reaped(keyframed, monkeypatch):
    monkeypatch.setattr(DF, "MIN_INTERVALS_PER_WORKER", 40)
    monkeypatch.setattr(DF, "BLOCK", 20)
    monkeypatch.setattr(DF, "can_fork", lambda n: True)
    real_part = DF._part

    def part(i):
        if i == 0:
            raise ValueError("part 0 failed")
        return real_part(i)

    monkeypatch.setattr(DF, "_part", part)
    children = []
    with pytest.raises(ValueError, match="part 0 failed"):
        with ForkedTasks(always_fork=True) as tasks:
            job = DF.start_densify_forked(tasks, *keyframed, workers=2)
            children += tasks.tasks
            job.result()
    assert len(children) == 2 and all(c.pid is None for c in children)  # both children waited for or killed
