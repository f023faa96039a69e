"""What the user sees: the demo (progress, closing verdict), report.html (sections present exactly when their data is,
self-contained, really renders in headless Chromium) and fused.mcap (Foxglove topics, rails,
raw inputs copied)."""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil

import numpy as np
import pytest

from trackfusion.cli import main
from trackfusion.demo import run_demo
from trackfusion.report.chromium import find_chromium, screenshot
from trackfusion.report.html import write_report
from trackfusion.sensors.fileio import read_csv_table, write_csv_table

SHORT = ["motion.passes=1",
         "motion.segments=[{hold_s: 20}, {move_to_m: 130, speed_mps: 3, accel_mps2: 0.4}, {hold_s: 5},"
         " {move_to_m: 40, speed_mps: 3, accel_mps2: 0.4}]"]
BASE_SECTIONS = {"summary", "trajectory", "sigmas", "relative-accuracy", "noise", "rejected"}
CONTRACT_SECTIONS = {"geometry", "time-sync", "registration", "faults"}


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """``trackfusion demo`` on a short survey: (folder, stdout, progress lines, its verdict)."""
    d = tmp_path_factory.mktemp("demo")
    said: list[str] = []
    with contextlib.redirect_stdout(io.StringIO()) as stdout:
        passed = run_demo(d, progress=said.append, seed=1, overrides=SHORT)
    return d, stdout.getvalue(), said, passed


@pytest.fixture(scope="module")
def run_dir(demo):
    return demo[0]


def test_demo_shows_progress_and_closes_with_the_verdict_and_where_results_are(demo):
    d, stdout, said, passed = demo
    for step in ("step 1/3: simulating", "step 2/3: checking the raw log", "step 3/3: fusing"):
        assert any(step in line for line in said), step
    assert any(line.startswith("solving:") for line in said) and any("writing the outputs" in x for x in said)
    metrics = json.loads((d / "out" / "metrics.json").read_text())
    verdict = "MEETS" if metrics["evaluation"]["passed"] else "DOES NOT MEET"
    assert passed == metrics["evaluation"]["passed"]
    tail = stdout.strip().splitlines()[-6:]
    assert tail[0].startswith(f"demo: the survey {verdict} the seed-002 thresholds at 5 m (MSE <= 0.67 mm, "
                              "ADEV <= 0.16 mm, vertical and lateral)")
    ra = metrics["relative_accuracy"]["vertical"]
    assert f"vertical  MSE {ra['mse_at_threshold_mm']:.3f} mm, ADEV {ra['adev_at_threshold_mm']:.3f} mm" in tail[1]
    assert tail[3] == f"demo: open the report: {(d / 'out' / 'report.html').resolve()}"
    assert f"results are in {(d / 'out').resolve()}/" in tail[4]


def _sections(text: str) -> set[str]:
    return set(re.findall(r"<section id='([^']+)'>", text))


def _add_contract_outputs(src, dst):
    """A copy of a run folder with the total-station, geometry and fault outputs: geometry.csv (columns of the
    helper brief, built from the simulator's rail truth) and metrics geometry / time_sync /
    registration / rejected_prism / faults."""
    shutil.copytree(src, dst)
    truth = read_csv_table(src.parent / "geometry_truth.csv")
    cols = {c: truth[c] for c in ("chainage_m", "left_e_m", "left_n_m", "left_u_m", "right_e_m", "right_n_m",
                                  "right_u_m", "gauge_m")}
    cols["cross_level_mm"] = (truth["left_u_m"] - truth["right_u_m"]) * 1e3
    cols["twist_3m_mm"] = np.r_[np.zeros(12), cols["cross_level_mm"][12:] - cols["cross_level_mm"][:-12]]
    for rail in ("left", "right"):
        for d in ("vertical", "lateral"):
            cols[f"{rail}_{d}_mm"] = truth[f"irr_{d}_{rail}"] * 1e3
            cols[f"{rail}_{d}_versine_10m_mm"] = 0.5 * cols[f"{rail}_{d}_mm"]
    write_csv_table(dst / "geometry.csv", cols, {c: ("m" if c.endswith("_m") else "mm") for c in cols}, "n",
                    {"lat_deg": 42.86, "lon_deg": 90.17, "h_m": 60.0})
    m = json.loads((dst / "metrics.json").read_text())
    m["geometry"] = {"step_m": 0.25, "length_m": 180.0, "exceedances": [
        {"check": "left_vertical_mm", "chainage_m": 77.25, "value_mm": 4.321, "limit_mm": 2.0}]}
    lags = np.linspace(-2, 2, 81)
    m["time_sync"] = {"TS1": {"offset_s": 0.35, "r_max": 0.998, "lags_s": lags.tolist(),
                              "r": np.exp(-(lags - 0.35) ** 2).tolist()}}
    stats = {"max_abs_mm": 1.2, "mean_mm": 0.1, "std_mm": 0.4, "slope_mm_per_m": 0.001}
    m["registration"] = {"method": "overlap", "stations": {"TS1": {"e_m": 1.0}, "TS2": {"e_m": 2.0}},
                         "residuals": {"before": {"lateral": stats}, "after": {"lateral": stats}}}
    m["rejected_prism"] = [{"station": "TS2", "t_s": 812.5, "reason": "prism hand-over gap"}]
    m["faults"] = {"gnss_outage": {"start_s": 100.0, "end_s": 160.0}}
    (dst / "metrics.json").write_text(json.dumps(m))


@pytest.fixture(scope="module")
def full_dir(run_dir, tmp_path_factory):
    d = tmp_path_factory.mktemp("full") / "out"
    _add_contract_outputs(run_dir / "out", d)
    write_report(d)
    return d


def test_run_writes_the_report_with_the_sections_it_has_data_for(run_dir):
    text = (run_dir / "out" / "report.html").read_text()
    assert _sections(text) == BASE_SECTIONS | {"geometry", "faults"}  # a run computes geometry and fault checks
    passed = json.loads((run_dir / "out" / "metrics.json").read_text())["evaluation"]["passed"]
    verdict = f"<p class='verdict {'pass' if passed else 'fail'}'>The survey {'MEETS' if passed else 'DOES NOT MEET'}"
    assert verdict + " the thresholds at 5 m (MSE &le; 0.67 mm, ADEV &le; 0.16 mm, vertical and lateral)" in text
    assert str((run_dir / "out").resolve()) in text  # the output folder, not the staging folder
    assert ".out-" not in text
    assert "<td>nhc</td><td>lateral</td>" in text and "<td>gnss (white)</td>" in text  # the estimated noise


def test_contract_sections_render_when_their_data_is_present(full_dir):
    text = (full_dir / "report.html").read_text()
    assert _sections(text) == BASE_SECTIONS | CONTRACT_SECTIONS
    assert "77.25" in text and "4.32" in text and "id='exc-E1'" in text  # the exceedance row, an anchor
    assert "prism hand-over gap" in text and "gnss_outage" in text and "slope_mm_per_m" in text
    assert text.count("data:image/png;base64,") == 7  # plan, sigmas, accuracy, 3 geometry, time sync


def test_report_is_self_contained(full_dir):
    text = (full_dir / "report.html").read_text()
    assert "<script" not in text and "<link" not in text and "url(" not in text
    assert not re.search(r"(src|href)='(?!data:|#)", text)
    assert "http://" not in text and "https://" not in text


def test_report_command_refuses_a_folder_without_run_files(tmp_path, capsys):
    assert main(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "metrics.json" in err[0]


def test_report_renders_in_headless_chromium(full_dir, tmp_path):
    from matplotlib.image import imread

    if find_chromium() is None:
        if os.environ.get("TRACKFUSION_REQUIRE_CHROMIUM"):
            pytest.fail("chromium not found but TRACKFUSION_REQUIRE_CHROMIUM is set (.ci/run installs it)")
        pytest.skip("chromium not installed (apt-get install chromium; .ci/run installs it)")

    png = tmp_path / "shot.png"
    screenshot(full_dir / "report.html", png, width_px=1200, height_px=4000)
    rgb = (imread(png)[..., :3] * 255).round().astype(int)
    assert rgb.shape == (4000, 1200, 3)
    ink = np.any(rgb < 200, axis=2).mean()
    assert ink > 0.02, f"screenshot nearly blank ({ink:.3%} ink)"
    top = rgb[:400]
    # the verdict banner's background (#dafbe1 pass / #ffebe9 fail) is drawn near the top
    banner = np.all(np.abs(top - [218, 251, 225]) <= 2, axis=2) | np.all(np.abs(top - [255, 235, 233]) <= 2, axis=2)
    assert banner.sum() > 5000
    # the embedded figures rendered: matplotlib's C0 blue (#1f77b4) lines are on the page
    blue = np.all(np.abs(rgb - [31, 119, 180]) <= 12, axis=2).sum()
    assert blue > 2000


def _messages(path, topics=None) -> dict[str, list]:
    from mcap.reader import make_reader

    out: dict[str, list] = {}
    with open(path, "rb") as fh:
        for schema, channel, msg in make_reader(fh).iter_messages(topics=topics, log_time_order=True):
            out.setdefault(channel.topic, []).append((schema.name, channel.message_encoding, msg.log_time, msg.data))
    return out


def test_fused_mcap_holds_the_trajectory_and_copies_the_raw_topics(run_dir):
    from trackfusion.sensors.fused import survey_epoch_ns
    from trackfusion.sensors.mcap_log import read_log

    fused = _messages(run_dir / "out" / "fused.mcap")
    raw = _messages(run_dir / "log.mcap")
    epoch = survey_epoch_ns(read_log(run_dir / "log.mcap", topics=[]).metadata)
    assert epoch > 1.7e18  # the simulated survey's epoch: fused.mcap on the absolute clock
    for topic, msgs in raw.items():
        moved = [(s, e, t + epoch, d) for s, e, t, d in msgs]
        assert fused[topic] == moved, topic  # schema, encoding and bytes identical, log_time + the epoch
    assert set(fused) == set(raw) | {"/trajectory/pose", "/trajectory/fix", "/trajectory/path", "/track/rails",
                                     "/track/rails_geojson", "/trajectory/tf"}  # the run writes geometry.csv, so rails too
    poses, fixes = fused["/trajectory/pose"], fused["/trajectory/fix"]
    assert {p[:2] for p in poses} == {("foxglove.PoseInFrame", "json")}
    assert {f[:2] for f in fixes} == {("foxglove.LocationFix", "json")}
    traj = read_csv_table(run_dir / "out" / "trajectory.csv")
    assert len(poses) == pytest.approx((traj["t_s"][-1] - traj["t_s"][0]) * 10, abs=2)  # 10 Hz
    p = json.loads(poses[5][3])
    i = int(np.argmin(np.abs(traj["t_s"] - (poses[5][2] - epoch) / 1e9)))
    assert p["frame_id"] == "n" and p["pose"]["position"]["x"] == pytest.approx(traj["e_m"][i], abs=1e-9)
    q = p["pose"]["orientation"]
    assert q["w"] == pytest.approx(traj["qw"][i]) and np.isclose(sum(v * v for v in q.values()), 1.0)
    f = json.loads(fixes[5][3])
    assert f["position_covariance_type"] == 2 and len(f["position_covariance"]) == 9
    assert f["position_covariance"][8] == pytest.approx(traj["sigma_u_m"][i] ** 2)
    assert abs(f["latitude"] - 42.86) < 0.01 and abs(f["longitude"] - 90.17) < 0.01
    scene = json.loads(fused["/trajectory/path"][0][3])
    line = scene["entities"][0]["lines"][0]
    assert scene["entities"][0]["frame_id"] == "n" and line["type"] == 0 and len(line["points"]) > 1000


def test_fused_mcap_draws_the_rails_of_geometry_csv(run_dir, full_dir, tmp_path):
    from trackfusion.geodesy import Origin
    from trackfusion.sensors.fused import write_fused_mcap

    traj = read_csv_table(run_dir / "out" / "trajectory.csv")
    geometry = read_csv_table(full_dir / "geometry.csv")
    write_fused_mcap(tmp_path / "f.mcap", traj, Origin(42.86, 90.17, 60.0), geometry=geometry)
    msgs = _messages(tmp_path / "f.mcap")
    assert set(msgs) == {"/trajectory/pose", "/trajectory/fix", "/trajectory/tf", "/trajectory/path", "/track/rails",
                         "/track/rails_geojson"}
    (name, enc, t_ns, data), = msgs["/track/rails"]
    assert name == "foxglove.SceneUpdate" and t_ns == msgs["/trajectory/pose"][0][2]
    left, right = json.loads(data)["entities"][0]["lines"]
    assert len(left["points"]) == geometry["chainage_m"].size
    assert left["points"][7] == {"x": geometry["left_e_m"][7], "y": geometry["left_n_m"][7],
                                 "z": geometry["left_u_m"][7]}
    assert right["points"][-1]["y"] == geometry["right_n_m"][-1]
    (name, _, _, data), = msgs["/track/rails_geojson"]
    fc = json.loads(json.loads(data)["geojson"])
    assert name == "foxglove.GeoJSON" and [f["geometry"]["type"] for f in fc["features"]] == ["LineString"] * 2
    lon, lat, _ = fc["features"][0]["geometry"]["coordinates"][0]
    assert abs(lat - 42.86) < 0.01 and abs(lon - 90.17) < 0.01


def _report_of(full_dir, tmp_path, geometry_metrics: dict, nan_columns: tuple[str, ...] = ()) -> str:
    """The report of a copy of ``full_dir`` with ``metrics.geometry`` replaced and some geometry
    columns made all-NaN (not measured)."""
    d = tmp_path / "copy"
    shutil.copytree(full_dir, d)
    m = json.loads((d / "metrics.json").read_text())
    m["geometry"] = geometry_metrics
    (d / "metrics.json").write_text(json.dumps(m))
    if nan_columns:
        g = read_csv_table(d / "geometry.csv")
        for c in nan_columns:
            g[c] = np.full_like(g[c], np.nan)
        write_csv_table(d / "geometry.csv", g, {c: ("m" if c.endswith("_m") else "mm") for c in g}, "n",
                        {"lat_deg": 42.86, "lon_deg": 90.17, "h_m": 60.0})
    write_report(d)
    return (d / "report.html").read_text()


def _geometry_text(text: str) -> str:
    return re.search(r"<section id='geometry'>.*?</section>", text, re.S).group(0)


def test_report_says_when_no_tolerance_table_was_given(full_dir, tmp_path):
    text = _geometry_text(_report_of(full_dir, tmp_path, {"step_m": 0.25, "tolerance_table": None,
                                                         "exceedances": [], "skipped_checks": []}))
    assert "No tolerance table given" in text and "No exceedance" not in text


def test_report_says_skipped_checks_are_skipped_and_why(full_dir, tmp_path):
    skipped = [{"check": "shortwave_30m_5m", "reason": "needs a design alignment (inputs.design)"},
               {"check": "longwave_300m_150m", "reason": "needs a design alignment (inputs.design)"}]
    checks = [{"name": s["check"], "kind": "chord_indicator", "columns": [], "levels_mm": {"limit": 2.0}}
              for s in skipped]
    text = _geometry_text(_report_of(full_dir, tmp_path, {"step_m": 0.25, "tolerance_table": "seed002-china",
                                                         "tolerance_checks": checks, "exceedances": [],
                                                         "skipped_checks": skipped}))
    assert "Not checked: every check of table <b>seed002-china</b> was skipped" in text
    assert text.count("needs a design alignment (inputs.design)") == 2 and "No exceedance" not in text


def test_report_draws_levels_links_exceedances_and_shows_unmeasured_columns(full_dir, tmp_path):
    levels = {"alert": 1.0, "intervention": 2.0, "immediate_action": 4.0}
    gm = {"step_m": 0.25, "tolerance_table": "mine",
          "tolerance_checks": [{"name": "ll", "kind": "limit", "columns": ["left_vertical_mm", "right_vertical_mm"],
                                "levels_mm": levels}],
          "exceedances": [{"check": "ll:left_vertical_mm", "column": "left_vertical_mm", "from_m": 70.0, "to_m": 72.5,
                           "length_m": 2.75, "chainage_m": 71.0, "value_mm": -2.5049, "level": "intervention",
                           "limit_mm": 2.0}],
          "skipped_checks": [], "quality_index": {"section_m": 200.0, "columns": {"left longitudinal level": "left_vertical_mm"},
                                                  "not_measured": ["right alignment"],
                                                  "sections": [{"from_m": 0.0, "to_m": 200.0, "left longitudinal level": 1.2345}]}}
    text = _geometry_text(_report_of(full_dir, tmp_path, gm, ("right_lateral_mm", "right_lateral_versine_10m_mm")))
    row = re.search(r"<tr id='exc-E1'>(.*?)</tr>", text).group(1)
    assert [re.sub("<[^>]+>", "", c) for c in re.findall(r"<td>(.*?)</td>", row)] == \
        ["E1", "ll", "left longitudinal level", "70.00", "72.50", "2.75", "-2.50", "71.00", "intervention", "2.00"]
    assert "href='#fig-irregularities'" in row and "id='fig-irregularities'" in text
    assert re.search(r"<area shape='rect' coords='\d+,\d+,\d+,\d+' href='#exc-E1'", text)
    assert "Not measured (not drawn): right alignment, right lateral versine, 10 m chord" in text
    assert "<td>1.23</td>" in text and "Not measured: right alignment" in text
    assert "-0.00" not in text and "_mm (mm)" not in text
