"""End to end: an ideal simulated survey through ``trackfusion run`` -> geometry.csv against geometry_truth.csv.

The ideal log (no sensor errors, with a gauge sensor) on an irregular track, with the design
alignment given: the rail traces, versines and design-referenced irregularities must come
back as the truth's (the geometry chain adds no modelling error); bad geometry inputs fail
before any work with exit code 2 and nothing written.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from trackfusion.cli import main
from trackfusion.sensors.fileio import read_csv_table, read_sidecar
from trackfusion.simulation.scenarios import simulate_to_dir
from trackfusion.track.versines import symmetric_versine

SHORT = ["motion.passes=1", "motion.start_m=40",
         "motion.segments=[{hold_s: 40}, {move_to_m: 140, speed_mps: 3, accel_mps2: 0.4}, {hold_s: 10},"
         " {move_to_m: 40, speed_mps: 2, accel_mps2: 0.4}, {hold_s: 10}]",
         "gauge.rate_hz=50"]
LEAD = ["chainage_m", "left_e_m", "left_n_m", "left_u_m", "right_e_m", "right_n_m", "right_u_m",
        "gauge_m", "cross_level_mm", "twist_3m_mm", "twist_18.8976m_mm"]


@pytest.fixture(scope="module")
def ideal(tmp_path_factory):
    d = tmp_path_factory.mktemp("geometry_ideal")
    simulate_to_dir("open-track-gnss", d, seed=2, ideal=True, overrides=SHORT)
    config = json.loads((d / "truth.json").read_text())["config"]
    (d / "design.yaml").write_text(yaml.safe_dump({"alignment": config["alignment"]}))
    p = yaml.safe_load((d / "pipeline.yaml").read_text())
    p["inputs"]["design"] = "design.yaml"
    p["geometry"] = {"chords_m": [10.0], "twist_bases_m": [3.0], "tolerances": "fra-213-class5",
                     "asymmetric_chords": [{"before_m": 2.0, "after_m": 8.0}]}
    (d / "geometry.yaml").write_text(yaml.safe_dump(p))
    assert main(["run", str(d / "geometry.yaml"), "--out", str(d / "out")]) == 0
    return d


@pytest.mark.slow
def test_geometry_csv_follows_the_contract(ideal):
    g = read_csv_table(ideal / "out" / "geometry.csv")
    names = list(g)
    assert names[:len(LEAD)] == LEAD
    for side in ("left", "right"):
        for comp in ("vertical", "lateral"):
            assert f"{side}_{comp}_mm" in g and f"{side}_{comp}_versine_10m_mm" in g
            assert f"{side}_{comp}_versine_2+8m_mm" in g
    side = read_sidecar(ideal / "out" / "geometry.csv")
    assert side["frame"] == "n" and set(side["origin"]) == {"lat_deg", "lon_deg", "h_m"}
    assert side["columns"]["cross_level_mm"] == "mm" and side["columns"]["left_e_m"] == "m"
    m = json.loads((ideal / "out" / "metrics.json").read_text())["geometry"]
    assert m["step_m"] == 0.25 and m["length_m"] == pytest.approx(g["chainage_m"][-1] - g["chainage_m"][0])
    assert m["chainage"] == "design (projection)" and m["passes"] == 2
    assert isinstance(m["exceedances"], list)
    for e in m["exceedances"]:
        assert set(e) >= {"check", "chainage_m", "value_mm", "limit_mm"}


@pytest.mark.slow
def test_ideal_run_geometry_matches_the_truth(ideal):
    g = read_csv_table(ideal / "out" / "geometry.csv")
    t = read_csv_table(ideal / "geometry_truth.csv")
    s, st = g["chainage_m"], t["chainage_m"]
    assert s[0] >= st[0] - 1e-9 and s[-1] <= st[-1] + 1e-9 and s.size > 350
    for side in ("left", "right"):
        rail_t = np.column_stack([t[f"{side}_{c}_m"] for c in "enu"])
        rail = np.column_stack([g[f"{side}_{c}_m"] for c in "enu"])
        assert np.abs(rail - np.column_stack([np.interp(s, st, rail_t[:, i]) for i in range(3)])).max() < 1e-3
        v_t, l_t = symmetric_versine(st, rail_t, 10.0, s)
        for comp, ref in (("vertical", v_t), ("lateral", l_t)):
            e = g[f"{side}_{comp}_versine_10m_mm"] - 1e3 * ref
            ok = np.isfinite(e)
            assert ok.sum() > 300 and np.sqrt(np.mean(e[ok] ** 2)) < 0.01, (side, comp)
            # against the design, the irregularity is the simulated one
            irr_t = 1e3 * np.interp(s, st, t[f"irr_{comp}_{side}"])
            assert np.sqrt(np.nanmean((g[f"{side}_{comp}_mm"] - irr_t) ** 2)) < 0.2
            assert np.std(irr_t) > 1.0  # the track is irregular: the comparison means something
    assert np.abs(g["gauge_m"] - np.interp(s, st, t["gauge_m"])).max() < 1e-4
    cl_t = 1e3 * (np.interp(s, st, t["left_u_m"]) - np.interp(s, st, t["right_u_m"]))
    assert np.abs(g["cross_level_mm"] - cl_t).max() < 0.05


@pytest.mark.parametrize("change,message", [
    ({"geometry": {"tolerances": "no-such-table"}}, "not found"),
    ({"geometry": {"chords_m": "ten"}}, "geometry.chords_m"),
    ({"inputs": {"design": "missing.yaml"}}, "inputs.design"),
])
def test_bad_geometry_inputs_exit_2_before_running(tmp_path, capsys, change, message):
    log = tmp_path / "log.mcap"
    log.write_bytes(b"")
    p = {"inputs": {"log": "log.mcap"}, "trolley": {"wheelbase_m": 1.0, "lever_arm_imu_v_m": [0, 0, 0.2]},
         "sensors": {"imu": {"grade": "navigation"}}, "factors": {"gnss": False}}
    for k, v in change.items():
        p.setdefault(k, {}).update(v)
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(p))
    assert main(["run", str(tmp_path / "p.yaml"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()
