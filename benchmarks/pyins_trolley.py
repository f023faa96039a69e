"""Benchmark: a trolley survey made by an independent simulator (``pyins``), run through a
datasheet-only pipeline.

Usage: python benchmarks/pyins_trolley.py [--seed 1] [--minutes 15] [--work DIR] [--no-json]

The survey (all drawn here, nothing by trackfusion's simulator):

* Track design: 1.35 km (15 min at 1.5 m/s) of straight, a 300 m clothoid-curve-clothoid right
  hand bend (radius 1,200 m, 60 mm cant, clothoids of 80 m) and straight, on a 2 per mille
  grade with a 1,500 m crest. Irregularities of the reference (left) rail: vertical and
  lateral, sums of 60 sines with wavelengths 3-120 m (amplitude ~ wavelength, 1.2 mm RMS
  vertical, 0.9 mm lateral), cross-level 0.5 mm RMS.
* The rigid trolley: both reference-rail wheels on the rail (wheelbase 1.2 m), ``v`` origin
  midway, x along their chord, roll the cant plus cross-level; the IMU 0.7175 m right of the
  rail and 0.25 m up. Motion: 60 s at rest, a raised-cosine start (0.3 m/s^2) to 1.5 m/s, a
  stop, 30 s at rest.
* IMU: ``pyins.sim.generate_imu`` from the IMU's geodetic trajectory and attitude (pyins' own
  Earth and gravity models), errors by ``pyins.inertial_sensor.Parameters`` (white noise,
  constant bias, bias random walk, scale and misalignment): 2.5x the navigation grade's white
  noise (ARW 0.0025 deg/sqrt(h), VRW 0.0075 m/s/sqrt(h)), bias 0.01 deg/h and 10 ug (1 sigma).
  200 Hz, written as text in pyins' axes (forward-right-down: ``axes: frd``).
* RTK GNSS at 1 Hz: white 8 / 15 mm (horizontal / vertical) plus a Gauss-Markov error of
  10 / 20 mm with 120 s, stated accuracy 10 / 20 mm (the receiver's datasheet).
* Odometer at 100 Hz: 8,192 ticks a revolution of a 0.2 m wheel, scale error 0.2 % (``--scale-ppm``)
  plus ``--drift-ppm-per-h``, ticks counted, no slips.

The files are text (CSV), imported with ``trackfusion import`` (docs/import.md); the pipeline
carries only datasheet values: ``grade: navigation`` (nominal figures), the antenna lever arm,
the trolley's drawing (wheelbase, IMU lever arm), the receiver's stated accuracy (in the fixes'
sigma columns); the smoother's defaults for everything else.

Prints the 5 m vertical / lateral MSE and Allan deviation (trackfusion/evaluation/relative.py,
through the run's reference evaluation), the odometer scale estimated against the truth and the
slips reported; writes benchmarks/results/pyins_trolley.json.
Targets: 5 m ADEV <= 0.12 mm (seed 002's 0.16 mm with margin), MSE <= 0.67 mm; odometer scale
within 100 ppm of the truth; no slip reported.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

RESULTS = Path(__file__).resolve().parent / "results" / "pyins_trolley.json"
CACHE = Path(tempfile.gettempdir()) / "trackfusion-bench"
ORIGIN = {"lat_deg": 48.1, "lon_deg": 11.5, "h_m": 520.0}
WHEELBASE_M = 1.2
LEVER_ARM_IMU_V_M = (0.0, -0.7175, 0.25)
GNSS_LEVER_ARM_B_M = (0.0, -0.2, 1.3)
IMU_RATE_HZ, ODO_RATE_HZ, GNSS_RATE_HZ, TRUTH_RATE_HZ = 200.0, 100.0, 1.0, 100.0
SPEED_MPS, ACCEL_MPS2 = 1.5, 0.3
TICKS_PER_REV, WHEEL_DIAMETER_M = 8192, 0.2
#: navigation grade's nominal white noise (trackfusion/sensors/imu.py) times this
IMU_NOISE_FACTOR = 2.5
TARGET_ADEV_MM, TARGET_MSE_MM, TARGET_SCALE_PPM = 0.12, 0.67, 100.0


# --- the track design --------------------------------------------------------------------------

def _curvature_per_m(s: np.ndarray, start_m: float, clothoid_m: float, arc_m: float, radius_m: float) -> np.ndarray:
    """Signed curvature (N,) [1/m] of a clothoid-arc-clothoid bend starting at ``start_m`` (right: < 0)."""
    a, b, c, d = start_m, start_m + clothoid_m, start_m + clothoid_m + arc_m, start_m + 2 * clothoid_m + arc_m
    k = np.interp(s, [a, b, c, d], [0.0, 1.0, 1.0, 0.0], left=0.0, right=0.0)
    return -k / radius_m


def _irregularity_m(s: np.ndarray, rms_m: float, rng: np.random.Generator) -> np.ndarray:
    """Sum of 60 sines (wavelengths 3-120 m, amplitude ~ wavelength), scaled to ``rms_m``."""
    lam = np.geomspace(3.0, 120.0, 60)
    amp = lam * rng.uniform(0.5, 1.5, lam.size)
    phase = rng.uniform(0, 2 * np.pi, lam.size)
    amp *= rms_m / np.sqrt(0.5 * np.sum(amp**2))
    out = np.zeros_like(s)
    for a, l, p in zip(amp, lam, phase):
        out += a * np.sin(2 * np.pi * s / l + p)
    return out


@dataclass
class Rail:
    """The reference rail as built: design parameter ``s_m`` (M,), points ``p_n_m`` (M, 3) in
    ENU at the origin, its own arc length ``arc_m`` (M,), cross-level angle ``roll_rad`` (M,)."""

    s_m: np.ndarray
    p_n_m: np.ndarray
    arc_m: np.ndarray
    roll_rad: np.ndarray


def build_rail(length_m: float, rng: np.random.Generator, step_m: float = 0.05) -> Rail:
    """The rail from the design (straight, bend, straight; grade and crest) and its irregularities."""
    s = np.arange(-20.0, length_m + 20.0 + step_m, step_m)
    bend_start = 0.3 * length_m
    kappa = _curvature_per_m(s, bend_start, 80.0, 300.0, 1200.0)
    heading = 0.35 + np.concatenate([[0.0], np.cumsum(0.5 * (kappa[1:] + kappa[:-1]) * step_m)])  # from east, CCW
    grade = np.clip(0.002 - np.clip(s - 0.6 * length_m, 0.0, None) / 1500.0, -0.004, None)  # the crest
    x = np.concatenate([[0.0], np.cumsum(0.5 * (np.cos(heading[1:]) + np.cos(heading[:-1])) * step_m)])
    y = np.concatenate([[0.0], np.cumsum(0.5 * (np.sin(heading[1:]) + np.sin(heading[:-1])) * step_m)])
    z = np.concatenate([[0.0], np.cumsum(0.5 * (grade[1:] + grade[:-1]) * step_m)])
    left = np.column_stack([-np.sin(heading), np.cos(heading), np.zeros_like(s)])
    lateral = _irregularity_m(s, 0.9e-3, rng)
    vertical = _irregularity_m(s, 1.2e-3, rng)
    p = np.column_stack([x, y, z + vertical]) + left * lateral[:, None]
    cant_rad = np.abs(kappa) * 1200.0 * 0.060 / 1.5  # 60 mm over 1.5 m on the arc
    roll = -cant_rad * np.sign(-kappa) + _irregularity_m(s, 0.5e-3, rng) / 1.5  # right bend: left rail up
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    arc -= np.interp(0.0, s, arc)
    return Rail(s, p, arc, roll)


def motion_s(t: np.ndarray, length_m: float, rest_start_s: float = 60.0) -> np.ndarray:
    """Design position s(t) (N,) [m]: rest, raised-cosine start to ``SPEED_MPS``, cruise, stop."""
    ramp_s = 2.0 * SPEED_MPS / ACCEL_MPS2  # peak acceleration ACCEL_MPS2 of the raised cosine
    ramp_m = 0.5 * SPEED_MPS * ramp_s
    cruise_s = (length_m - 2 * ramp_m) / SPEED_MPS
    tau = t - rest_start_s

    def ramp_dist(u):  # distance of a 0 -> SPEED raised-cosine speed ramp after time u
        u = np.clip(u, 0.0, ramp_s)
        return SPEED_MPS * (0.5 * u - 0.5 * ramp_s / np.pi * np.sin(np.pi * u / ramp_s))

    s = ramp_dist(tau) + SPEED_MPS * np.clip(tau - ramp_s, 0.0, cruise_s)
    t_dec = tau - ramp_s - cruise_s
    dec = np.clip(t_dec, 0.0, ramp_s)
    s += np.where(t_dec > 0, SPEED_MPS * dec - ramp_dist(dec), 0.0)
    return s


def run_duration_s(length_m: float, rest_start_s: float = 60.0, rest_end_s: float = 30.0) -> float:
    """Duration [s] of :func:`motion_s` over ``length_m`` with its rests."""
    ramp_s = 2.0 * SPEED_MPS / ACCEL_MPS2
    return rest_start_s + 2 * ramp_s + (length_m - ramp_s * SPEED_MPS) / SPEED_MPS + rest_end_s


# --- the trolley's motion -------------------------------------------------------------------------

def trolley_pose(rail: Rail, s_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """IMU position (N, 3) [m, ENU] and R_nb (N, 3, 3) (body = trolley frame, x forward, y left,
    z up) with the reference-rail wheels at design positions ``s_m -+ WHEELBASE_M / 2``."""
    from scipy.interpolate import CubicSpline
    spline = CubicSpline(rail.s_m, rail.p_n_m)
    rear, front = spline(s_m - 0.5 * WHEELBASE_M), spline(s_m + 0.5 * WHEELBASE_M)
    chord = front - rear
    x = chord / np.linalg.norm(chord, axis=1)[:, None]
    yaw, pitch = np.arctan2(x[:, 1], x[:, 0]), np.arcsin(x[:, 2])
    roll = CubicSpline(rail.s_m, rail.roll_rad)(s_m)
    from scipy.spatial.transform import Rotation
    R_nb = Rotation.from_euler("ZYX", np.column_stack([yaw, -pitch, roll])).as_matrix()  # Rz Ry Rx
    pos = 0.5 * (rear + front) + R_nb @ np.asarray(LEVER_ARM_IMU_V_M)
    return pos, R_nb


#: ENU -> NED and flu -> frd
_C_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_C_FLU_FRD = np.diag([1.0, -1.0, -1.0])


def pyins_imu(t_s: np.ndarray, pos_n_m: np.ndarray, R_nb: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """IMU samples drawn by pyins: gyro (N, 3) [rad/s] and accel (N, 3) [m/s^2] in pyins' body
    axes (forward, right, down), with pyins' sensor error model."""
    import pymap3d
    from pyins import inertial_sensor, sim, transform
    lat, lon, h = pymap3d.enu2geodetic(pos_n_m[:, 0], pos_n_m[:, 1], pos_n_m[:, 2],
                                       ORIGIN["lat_deg"], ORIGIN["lon_deg"], ORIGIN["h_m"])
    # pyins' attitude is relative to the local north-east-down frame at each position (which
    # turns by ~160 urad/km against the origin's tangent frame ``n``)
    C_e_ned = transform.mat_en_from_ll(lat, lon)
    C_e_ned0 = transform.mat_en_from_ll(ORIGIN["lat_deg"], ORIGIN["lon_deg"])
    R_ned_frd = np.swapaxes(C_e_ned, 1, 2) @ (C_e_ned0 @ _C_NED_ENU) @ R_nb @ _C_FLU_FRD
    rph = transform.mat_to_rph(R_ned_frd)
    _, imu = sim.generate_imu(t_s, np.column_stack([lat, lon, h]), rph, sensor_type="rate")
    arw = IMU_NOISE_FACTOR * 0.001 * np.pi / 180 / 60        # rad/sqrt(s)
    vrw = IMU_NOISE_FACTOR * 0.003 / 60                      # m/s/sqrt(s)
    rng = np.random.RandomState(seed)
    gyro_model = inertial_sensor.EstimationModel(bias_sd=0.01 * np.pi / 180 / 3600, noise=arw,
                                                 bias_walk=0.005 * np.pi / 180 / 3600 / 30.0, scale_misal_sd=1e-5)
    accel_model = inertial_sensor.EstimationModel(bias_sd=10e-6 * 9.80665, noise=vrw,
                                                  bias_walk=5e-6 * 9.80665 / 30.0, scale_misal_sd=1e-5)
    gp = inertial_sensor.Parameters.from_EstimationModel(gyro_model, rng)
    ap = inertial_sensor.Parameters.from_EstimationModel(accel_model, rng)
    out = inertial_sensor.apply_imu_parameters(imu, "rate", gp, ap)
    return out[["gyro_x", "gyro_y", "gyro_z"]].to_numpy(), out[["accel_x", "accel_y", "accel_z"]].to_numpy()


def _gauss_markov(n: int, sigma: float, tau_s: float, dt_s: float, rng: np.random.Generator) -> np.ndarray:
    """A stationary first-order Gauss-Markov sequence (n,)."""
    phi = np.exp(-dt_s / tau_s)
    w = rng.standard_normal(n) * sigma * np.sqrt(1 - phi**2)
    w[0] = rng.standard_normal() * sigma
    from scipy.signal import lfilter
    return lfilter([1.0], [1.0, -phi], w)


def odometer_counts(t_s: np.ndarray, wheel_arc_m: np.ndarray, scale: float, drift_per_h: float,
                    steps: list[tuple[float, float]] = ()) -> tuple[np.ndarray, np.ndarray]:
    """Distance (N,) [m] and ticks (N,) of the odometer: true rolled distance increments times
    ``1 + scale + drift_per_h (t - t0) / 3600``, plus ``steps`` (time [s], extra distance [m]: a
    slip), counted in ticks (floor)."""
    inc = np.diff(wheel_arc_m - wheel_arc_m[0], prepend=0.0)
    d = np.cumsum(inc * (1.0 + scale + drift_per_h * (t_s - t_s[0]) / 3600.0))
    for at_s, extra_m in steps:
        d += extra_m * np.clip((t_s - at_s) / 0.3, 0.0, 1.0)  # 0.3 s of slipping
    ticks_per_m = TICKS_PER_REV / (np.pi * WHEEL_DIAMETER_M)
    ticks = np.floor(d * ticks_per_m + 1e-9).astype(np.int64)
    return ticks / ticks_per_m, ticks


# --- the survey's files -----------------------------------------------------------------------------

GNSS_WHITE_MM, GNSS_GM_MM, GNSS_GM_TAU_S, GNSS_STATED_MM = (8.0, 15.0), (10.0, 20.0), 120.0, (10.0, 20.0)


def _write_text(path: Path, header: str, columns: list[np.ndarray], fmt: str) -> None:
    np.savetxt(path, np.column_stack(columns), fmt=fmt, delimiter=",", header=header, comments="")


def _gnss_fixes(t_s: np.ndarray, antenna_n_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Antenna positions (F, 3) [m, ENU] plus white and Gauss-Markov error per axis."""
    err = np.empty_like(antenna_n_m)
    for i, axis in enumerate((0, 0, 1)):  # east, north: horizontal; up: vertical
        err[:, i] = (rng.standard_normal(t_s.size) * GNSS_WHITE_MM[axis] * 1e-3
                     + _gauss_markov(t_s.size, GNSS_GM_MM[axis] * 1e-3, GNSS_GM_TAU_S, 1.0 / GNSS_RATE_HZ, rng))
    return antenna_n_m + err


def make_survey(out: Path, seed: int = 1, minutes: float = 15.0, scale_ppm: float = 2000.0,
                drift_ppm_per_h: float = 0.0, slips: list[tuple[float, float]] = ()) -> dict:
    """Write the survey into folder ``out``: text files, ``import.yaml``, ``log.mcap`` (imported),
    ``truth.csv`` and the datasheet ``pipeline.yaml``. Returns the truth's summary (scale, drift,
    slips, lengths)."""
    import pymap3d
    from trackfusion.sensors.fileio import write_csv_table
    from trackfusion.sensors.importers import import_to_mcap
    from trackfusion.simulation.scenarios import TRUTH_COLUMNS

    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    length_m = minutes * 60.0 * SPEED_MPS
    rail = build_rail(length_m, rng)
    t = np.arange(int(run_duration_s(length_m) * IMU_RATE_HZ) + 1) / IMU_RATE_HZ
    s = motion_s(t, length_m)
    pos, R_nb = trolley_pose(rail, s)
    gyro, accel = pyins_imu(t, pos, R_nb, seed)
    _write_text(out / "imu.txt", "t_s,gx,gy,gz,ax,ay,az", [t, gyro, accel], "%.6f" + ",%.12e" * 6)

    t_odo = t[::int(IMU_RATE_HZ / ODO_RATE_HZ)]
    arc = np.interp(t_odo, t, np.interp(s - 0.5 * WHEELBASE_M, rail.s_m, rail.arc_m))  # the rear wheel
    dist, ticks = odometer_counts(t_odo, arc, scale_ppm * 1e-6, drift_ppm_per_h * 1e-6, slips)
    _write_text(out / "odometer.csv", "t_s,distance_m,ticks", [t_odo, dist, ticks], "%.6f,%.9f,%d")

    k = np.flatnonzero(np.isclose((t * GNSS_RATE_HZ) % 1.0, 0.0, atol=1e-6))
    antenna = pos[k] + R_nb[k] @ np.asarray(GNSS_LEVER_ARM_B_M)
    fix = _gnss_fixes(t[k], antenna, rng)
    lat, lon, h = pymap3d.enu2geodetic(fix[:, 0], fix[:, 1], fix[:, 2], ORIGIN["lat_deg"], ORIGIN["lon_deg"], ORIGIN["h_m"])
    sig = np.broadcast_to(np.array([GNSS_STATED_MM[0], GNSS_STATED_MM[0], GNSS_STATED_MM[1]]), (k.size, 3))
    _write_text(out / "gnss.csv", "t_s,lat,lon,h,se,sn,su", [t[k], lat, lon, h, sig], "%.6f,%.11f,%.11f,%.5f,%.1f,%.1f,%.1f")

    mapping = {"survey": {"name": f"pyins trolley (seed {seed})", "origin": ORIGIN},
               "imu": {"file": "imu.txt", "time": {"column": "t_s", "unit": "s"},
                       "gyro": {"columns": ["gx", "gy", "gz"], "unit": "rad/s"},
                       "accel": {"columns": ["ax", "ay", "az"], "unit": "m/s^2"}, "axes": "frd"},
               "odometer": {"file": "odometer.csv", "time": {"column": "t_s", "unit": "s"},
                            "distance": {"column": "distance_m", "unit": "m"}, "ticks": {"column": "ticks"}},
               "gnss": {"file": "gnss.csv", "time": {"column": "t_s", "unit": "s"},
                        "latitude": {"column": "lat", "unit": "deg"}, "longitude": {"column": "lon", "unit": "deg"},
                        "height": {"column": "h", "unit": "m"},
                        "sigma_enu": {"columns": ["se", "sn", "su"], "unit": "mm"}, "fix_quality": 4}}
    (out / "import.yaml").write_text(yaml.safe_dump(mapping, sort_keys=False))
    if (out / "log.mcap").exists():
        (out / "log.mcap").unlink()
    import_to_mcap(out / "import.yaml", out / "log.mcap")

    step = int(IMU_RATE_HZ / TRUTH_RATE_HZ)
    from scipy.spatial.transform import Rotation
    quat = Rotation.from_matrix(R_nb[::step]).as_quat()  # x, y, z, w
    vel = np.gradient(pos, t, axis=0)
    chain = np.interp(s, rail.s_m, rail.arc_m)
    truth = {"t_s": t[::step], "e_m": pos[::step, 0], "n_m": pos[::step, 1], "u_m": pos[::step, 2],
             "qw": quat[:, 3], "qx": quat[:, 0], "qy": quat[:, 1], "qz": quat[:, 2],
             "ve_mps": vel[::step, 0], "vn_mps": vel[::step, 1], "vu_mps": vel[::step, 2], "chainage_m": chain[::step]}
    info = {"scale_error_ppm": scale_ppm, "drift_ppm_per_h": drift_ppm_per_h,
            "slips": [{"t_s": a, "extra_m": b} for a, b in slips], "length_m": length_m,
            "duration_s": float(t[-1]), "imu_noise_factor": IMU_NOISE_FACTOR}
    if (out / "truth.csv").exists():
        (out / "truth.csv").unlink()
        (out / "truth.json").unlink(missing_ok=True)
    write_csv_table(out / "truth.csv", truth, TRUTH_COLUMNS, "n", ORIGIN, fmt="%.12g",
                    extra={"description": "truth of the IMU origin (pyins benchmark)", **info})
    (out / "pipeline.yaml").write_text(yaml.safe_dump(datasheet_pipeline(), sort_keys=False))
    return info


def datasheet_pipeline() -> dict:
    """The pipeline a surveyor writes from the datasheets and the trolley's drawing."""
    return {"name": "pyins-trolley",
            "inputs": {"log": "log.mcap", "reference": "truth.csv"},
            "origin": ORIGIN,
            "vehicle": {"kind": "trolley", "wheelbase_m": WHEELBASE_M, "reference_rail": "left",
                        "lever_arm_imu_v_m": list(LEVER_ARM_IMU_V_M), "mounting_ypr_deg": [0.0, 0.0, 0.0],
                        "odometer_wheel": "rear"},
            "sensors": {"imu": {"grade": "navigation"}, "odometer": {"clock_offset_s": 0.0},
                        "gnss": {"lever_arm_b_m": list(GNSS_LEVER_ARM_B_M), "clock_offset_s": 0.0}},
            "factors": {"imu": True, "zupt": True, "nhc": True, "odometer": True,
                        "wheel_path": {"enabled": True, "keyframe_step": 1}, "gnss": True,
                        "inclinometer": False, "total_stations": False},
            "keyframes": {"spacing_s": 0.2},
            "outputs": {"trajectory_rate_hz": TRUTH_RATE_HZ, "geometry_step_m": 0.25}}


def run_survey(folder: Path, out: Path):
    """Run the folder's pipeline into ``out``; its :class:`~trackfusion.pipeline.RunResult`."""
    from trackfusion.pipeline import load_pipeline, run
    return run(load_pipeline(folder / "pipeline.yaml"), out, force=True)


def scale_errors_ppm(result, info: dict) -> np.ndarray:
    """Estimated minus true odometer scale error [ppm] at the keyframes while moving (K,)."""
    sm = result.smoother
    t = sm.t_s
    speed = np.interp(t, result.trajectory["t_s"], np.linalg.norm(
        np.column_stack([result.trajectory[c] for c in ("ve_mps", "vn_mps", "vu_mps")]), axis=1))
    moving = speed > 0.5 * SPEED_MPS
    true_ppm = info["scale_error_ppm"] + info["drift_ppm_per_h"] * (t - t[0]) / 3600.0
    return (sm.odometer_scale * 1e6 - true_ppm)[moving]


# --- the benchmark ------------------------------------------------------------------------------------

def figures(result, info: dict) -> dict:
    """The benchmark's figures of one run: 5 m MSE / ADEV per axis [mm], scale error [ppm], slips."""
    m = result.metrics
    ra = m["relative_accuracy"]
    err = scale_errors_ppm(result, info)
    slips = m.get("faults", {}).get("odometer_slips", {}).get("events", [])
    out = {f"{c}_{k}_5m_mm": ra[c][f"{k}_at_threshold_mm"] for c in ("vertical", "lateral") for k in ("mse", "adev")}
    out.update({"scale_true_ppm": info["scale_error_ppm"], "scale_estimated_mean_ppm": m["odometer_scale_ppm"]["mean"],
                "scale_error_max_ppm": float(np.abs(err).max()), "scale_error_mean_ppm": float(err.mean()),
                "slips_reported": len(slips), "slips_true": len(info["slips"]),
                "gnss_rejected": len(m.get("rejected_gnss", [])),
                "abs_rms_mm": {c: m["absolute_error"][c]["rms_mm"] for c in ("along", "lateral", "vertical")}})
    out["pass"] = {"adev": max(out["vertical_adev_5m_mm"], out["lateral_adev_5m_mm"]) <= TARGET_ADEV_MM,
                   "mse": max(out["vertical_mse_5m_mm"], out["lateral_mse_5m_mm"]) <= TARGET_MSE_MM,
                   "scale": out["scale_error_max_ppm"] <= TARGET_SCALE_PPM,
                   "no_false_slip": out["slips_reported"] == out["slips_true"]}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--minutes", type=float, default=15.0)
    ap.add_argument("--scale-ppm", type=float, default=2000.0)
    ap.add_argument("--drift-ppm-per-h", type=float, default=0.0)
    ap.add_argument("--work", type=Path, default=CACHE)
    ap.add_argument("--no-json", action="store_true")
    args = ap.parse_args()
    folder = args.work / f"pyins-trolley-{args.seed}-{args.minutes:g}min-{args.scale_ppm:g}ppm-{args.drift_ppm_per_h:g}"
    tic = time.perf_counter()
    info = make_survey(folder, args.seed, args.minutes, args.scale_ppm, args.drift_ppm_per_h)
    made_s = time.perf_counter() - tic
    cpu = time.process_time()
    result = run_survey(folder, folder / "out")
    fig = figures(result, info)
    fig.update({"seed": args.seed, "minutes": args.minutes, "drift_ppm_per_h": args.drift_ppm_per_h,
                "imu_noise_factor": IMU_NOISE_FACTOR, "survey_s": made_s,
                "run_cpu_s_main_process": time.process_time() - cpu})
    print(f"pyins trolley survey, seed {args.seed}, {args.minutes:g} min at {SPEED_MPS} m/s, "
          f"odometer scale {args.scale_ppm:g} ppm, drift {args.drift_ppm_per_h:g} ppm/h")
    for c in ("vertical", "lateral"):
        print(f"  {c:8s} 5 m MSE {fig[f'{c}_mse_5m_mm']:.4f} mm (target <= {TARGET_MSE_MM}), "
              f"ADEV {fig[f'{c}_adev_5m_mm']:.4f} mm (target <= {TARGET_ADEV_MM})")
    print(f"  odometer scale: estimated {fig['scale_estimated_mean_ppm']:.1f} ppm (mean), error max "
          f"{fig['scale_error_max_ppm']:.1f} ppm while moving (target <= {TARGET_SCALE_PPM:g})")
    print(f"  slips reported {fig['slips_reported']} (true {fig['slips_true']}); pass: {fig['pass']}")
    if not args.no_json:
        RESULTS.parent.mkdir(exist_ok=True)
        RESULTS.write_text(json.dumps(fig, indent=2) + "\n")
        print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
