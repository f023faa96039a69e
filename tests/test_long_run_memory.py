"""Pieces of the long-run path that keep memory bounded: the block-wise CSV writer (same bytes as
the one-piece writer, nothing left on failure) and the IMU spilled to a mapped temporary file
(same values, pages released)."""

from __future__ import annotations

import numpy as np
import pytest

from trackfusion.sensors.fileio import CsvTableOnDisk, CsvTableWriter, write_csv_table
from trackfusion.sensors.spill import SpilledImu
from trackfusion.sensors.types import ImuData

ORIGIN = {"lat_deg": 47.0, "lon_deg": 8.0, "h_m": 400.0}
UNITS = {"t_s": "s", "e_m": "m", "flag": "1"}


def _table(n: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(3)
    return {"t_s": 1000.0 + 0.01 * np.arange(n), "e_m": rng.normal(0, 500, n), "flag": (rng.random(n) > 0.5) * 1.0}


def test_block_writer_gives_the_one_piece_bytes(tmp_path):
    table = _table(1003)
    write_csv_table(tmp_path / "one.csv", table, UNITS, "n", ORIGIN, extra={"x": 1}, fmt="%.12g")
    with CsvTableWriter(tmp_path / "blocks.csv", list(UNITS), UNITS, "n", ORIGIN, extra={"x": 1}, fmt="%.12g") as w:
        for a in (0, 1, 500, 999):  # uneven blocks, one of a single row
            w.write({k: v[a:{0: 1, 1: 500, 500: 999, 999: None}[a]] for k, v in table.items()})
    assert w.rows == 1003
    assert (tmp_path / "one.csv").read_bytes() == (tmp_path / "blocks.csv").read_bytes()
    assert (tmp_path / "one.json").read_bytes() == (tmp_path / "blocks.json").read_bytes()
    back = CsvTableOnDisk(tmp_path / "blocks.csv")
    assert list(back) == list(UNITS)
    np.testing.assert_allclose(back["e_m"], table["e_m"], rtol=1e-11)


def test_block_writer_leaves_nothing_on_failure(tmp_path):
    with pytest.raises(KeyError):
        with CsvTableWriter(tmp_path / "t.csv", list(UNITS), UNITS, "n", ORIGIN) as w:
            w.write(_table(10))
            w.write({"t_s": np.zeros(2)})  # a block without every column
    assert list(tmp_path.iterdir()) == []


def test_block_writer_refuses_a_column_without_unit(tmp_path):
    with pytest.raises(ValueError, match="no unit"):
        CsvTableWriter(tmp_path / "t.csv", ["t_s", "speed"], UNITS, "n", ORIGIN)
    assert list(tmp_path.iterdir()) == []


def _resident_kb(arr: np.ndarray) -> int:
    """Resident size [kB] of the mapping holding ``arr`` (from /proc/self/smaps)."""
    addr = arr.__array_interface__["data"][0]
    with open("/proc/self/smaps") as fh:
        inside = False
        for line in fh:
            head = line.split()[0]
            if "-" in head and ":" not in head:
                lo, hi = (int(x, 16) for x in head.split("-"))
                inside = lo <= addr < hi
            elif inside and head == "Rss:":
                return int(line.split()[1])
    raise AssertionError("mapping not found")


def test_spilled_imu_has_the_same_samples_and_releases_its_pages(tmp_path):
    n = 200_000
    rng = np.random.default_rng(1)
    imu = ImuData(0.002 * np.arange(n), rng.normal(size=(n, 3)), rng.normal(size=(n, 3)))
    spilled = SpilledImu(imu, tmp_path)
    assert list(tmp_path.iterdir()) == []  # an anonymous file: nothing visible, nothing left behind
    for a, b in zip((imu.t_s, imu.gyro_radps, imu.accel_mps2),
                    (spilled.imu.t_s, spilled.imu.gyro_radps, spilled.imu.accel_mps2)):
        np.testing.assert_array_equal(a, b)
        assert not b.flags.writeable
    touched = _resident_kb(spilled.imu.gyro_radps)
    assert touched >= 0.9 * imu.gyro_radps.nbytes / 1024
    spilled.release()
    assert _resident_kb(spilled.imu.gyro_radps) < 0.1 * touched
    np.testing.assert_array_equal(spilled.imu.accel_mps2[-5:], imu.accel_mps2[-5:])  # read again from the file


def test_spill_arrays_keep_what_is_written_after_release(tmp_path):
    from trackfusion.sensors.spill import SpillArrays

    rows = SpillArrays(tmp_path)
    a = rows.empty((100_000, 3))
    assert list(tmp_path.iterdir()) == [] and not a.any()
    values = np.random.default_rng(2).normal(size=a.shape)
    a[:] = values
    rows.release()
    assert _resident_kb(a) < 0.1 * a.nbytes / 1024
    np.testing.assert_array_equal(a, values)
