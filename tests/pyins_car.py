"""A road car's IMU + RTK survey made by an independent simulator, ``pyins`` (PyPI
``python-ins``), written as a ROS 2 bag by ``rosbags``' writer and as KF-GINS-style text.

Nothing here uses trackfusion's simulator or writers: the trajectory, the IMU increments and
the IMU errors are pyins' (``sim.generate_imu`` with exact per-interval increments,
``inertial_sensor.Parameters.from_EstimationModel`` for the errors), the bag is rosbags'.

Motion (``car_motion``): 120 s still, then driving with stops (20-40 s) every few minutes,
speeds 8-22 m/s reached at 0.5-1.5 m/s^2 (raised-cosine accelerations), turns of 40-400 m
radius at <= 2.5 m/s^2 lateral acceleration, a road profile of <= 5 % grade, the body rolling
4 deg per g outwards in turns, a 1.3 Hz suspension pitch of 0.05 deg at speed, and 60 s still at
the end. The motion is that of the rear axle's centre (no sideslip: heading = course, pitch =
the grade); the IMU sits ``IMU_V_M`` ahead of and above it, the antenna ``ANTENNA_B_M`` from the
IMU.

IMU: navigation grade (trackfusion's ``navigation`` datasheet: ARW 0.001 deg/sqrt(h), gyro bias
0.01 deg/h, VRW 0.003 m/s/sqrt(h), accel bias 10 ug, scale 10 / 20 ppm, misalignment 5 arcsec;
bias instability as pyins' bias random walk of the same one-hour spread), drawn by pyins.

RTK fixed fixes at ``gnss_rate_hz`` (1 Hz), stamped at whole seconds. True error per ENU axis:
white (8 mm horizontal, 15 mm vertical: a receiver's RTK datasheet, the carrier-phase noise and
multipath of a moving antenna, which decorrelate within a second at driving speed) plus a first-
order Gauss-Markov part (2 mm horizontal, 3 mm vertical, 600 s: the residual atmosphere and orbit
error over a few-km baseline, ~1 ppm, which changes over tens of minutes). Stated std
(NavSatFix covariance): ``honest`` the true total per axis; ``optimistic`` half of it (the
formal std of a carrier-phase solution, 2-3x optimistic on real receivers).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: IMU origin in the vehicle frame v (x forward, y left, z up; origin the rear axle's centre) [m]
IMU_V_M = np.array([1.2, 0.0, 0.4])
#: antenna phase centre from the IMU origin in b (x forward, y left, z up) [m]
ANTENNA_B_M = np.array([-0.3, 0.2, 1.1])
#: the ROS stamps' epoch offset [ns] of t = 0
EPOCH_NS = 1_700_000_000 * 10**9
LLA0 = (48.137, 11.575, 520.0)
WHITE_H_M, WHITE_V_M = 0.008, 0.015
CORR_H_M, CORR_V_M, CORR_TAU_S = 0.002, 0.003, 600.0
FLU = np.array([1.0, -1.0, -1.0])  # F-R-D (pyins' body axes) <-> F-L-U (REP-103)
DEG_H = np.pi / 180 / 3600


@dataclass
class CarSurvey:
    t_s: np.ndarray          #: (N,) IMU times from the first sample [s]
    gyro_inc_frd: np.ndarray  #: (N,3) angle increments over (t[i-1], t[i]] [rad], F-R-D
    accel_inc_frd: np.ndarray  #: (N,3) velocity increments [m/s], F-R-D
    lla_imu: np.ndarray      #: (N,3) true IMU origin [deg, deg, m]
    vel_ned: np.ndarray      #: (N,3) true IMU velocity [m/s]
    fix_t_s: np.ndarray      #: (F,)
    fix_lla: np.ndarray      #: (F,3) measured antenna position
    fix_std_enu_m: np.ndarray  #: (F,3) stated std
    fix_err_enu_m: np.ndarray  #: (F,3) the drawn error (truth only)


def _raised_cosine_steps(t: np.ndarray, times: np.ndarray, deltas: np.ndarray, durations: np.ndarray) -> np.ndarray:
    """Sum of smooth steps (N,): step k rises by deltas[k] over [times[k], times[k]+durations[k]]
    with a raised-cosine derivative."""
    out = np.zeros_like(t)
    for t0, d, T in zip(times, deltas, durations):
        x = np.clip((t - t0) / T, 0.0, 1.0)
        out += d * (x - np.sin(2 * np.pi * x) / (2 * np.pi))
    return out


def _bumps(t: np.ndarray, times: np.ndarray, peaks: np.ndarray, durations: np.ndarray) -> np.ndarray:
    """Sum of raised-cosine bumps (N,) of the given peaks over [times[k], times[k]+durations[k]]."""
    out = np.zeros_like(t)
    for t0, p, T in zip(times, peaks, durations):
        x = (t - t0) / T
        inside = (x > 0) & (x < 1)
        out[inside] += p * 0.5 * (1 - np.cos(2 * np.pi * x[inside]))
    return out


def car_motion(duration_s: float, rate_hz: float, rng: np.random.Generator):
    """Times (N,) [s], the rear axle's speed (N,) [m/s], heading, pitch and roll (N,) [deg] of
    a car (module docstring)."""
    t = np.arange(int(round(duration_s * rate_hz)) + 1) / rate_hz
    times, deltas, durs, v = [], [], [], 0.0
    tk, end = 120.0, duration_s - 60.0
    while True:  # accelerate, cruise, change speed, brake, stop
        plan = [rng.uniform(8, 22)] + [rng.uniform(8, 22) for _ in range(rng.integers(0, 3))] + [0.0]
        for target in plan:
            T = max(abs(target - v) / rng.uniform(0.5, 1.5), 2.0)
            cruise = rng.uniform(20, 90) if target > 0 else rng.uniform(20, 40)
            if tk + T + cruise > end and target > 0:
                target, T = 0.0, max(v / 1.0, 2.0)
            times.append(tk), deltas.append(target - v), durs.append(T)
            tk, v = tk + T + cruise, target
            if target == 0.0:
                break
        if tk > end - 60 or (v == 0.0 and tk + 60 > end):
            break
    speed = np.maximum(_raised_cosine_steps(t, np.array(times), np.array(deltas), np.array(durs)), 0.0)
    dist = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) / rate_hz)])
    # turns: curvature bumps over distance, |a_lat| <= 2.5 m/s^2 at the local top speed
    n_turns = int(dist[-1] / 400)
    s0 = np.sort(rng.uniform(0, dist[-1], n_turns))
    length = rng.uniform(40, 200, n_turns)
    vmax = np.interp(s0 + length / 2, dist, speed) + 1.0
    kappa = rng.choice([-1, 1], n_turns) * np.minimum(1 / rng.uniform(40, 400, n_turns), 2.5 / vmax**2)
    curv = _bumps(dist, s0, kappa, length)  # [1/m]
    yaw_rate = speed * curv
    heading = 30.0 + np.rad2deg(np.concatenate([[0.0], np.cumsum(0.5 * (yaw_rate[1:] + yaw_rate[:-1]) / rate_hz)]))
    k = 2 * np.pi * rng.uniform(1 / 2000, 1 / 300, 4)
    grade = sum(a * np.sin(kk * dist + rng.uniform(0, 2 * np.pi)) for a, kk in zip(rng.uniform(0.005, 0.0125, 4), k))
    pitch = np.rad2deg(np.arctan(grade)) + 0.05 * np.sin(2 * np.pi * 1.3 * t) * np.minimum(speed / 10, 1)
    roll = -np.rad2deg(4 * np.pi / 180 / 9.81 * speed * yaw_rate)  # FRD roll: outwards in a turn
    return t, speed, heading, np.rad2deg(np.arctan(grade)), pitch, roll


def _gauss_markov(n: int, dt: float, sigma: np.ndarray, tau: float, rng: np.random.Generator) -> np.ndarray:
    """(n, len(sigma)) stationary first-order Gauss-Markov samples (a linear filter: scipy)."""
    from scipy.signal import lfilter
    phi = np.exp(-dt / tau)
    w = rng.normal(size=(n, sigma.size)) * sigma * np.sqrt(1 - phi**2)
    w[0] = rng.normal(size=sigma.size) * sigma
    return lfilter([1.0], [1.0, -phi], w, axis=0)


def make_car_survey(duration_s: float = 3420.0, rate_hz: float = 200.0, gnss_rate_hz: float = 1.0,
                    stated: str = "honest", seed: int = 1, ideal: bool = False) -> CarSurvey:
    """The survey of the module docstring drawn with ``seed`` (``ideal``: without IMU and fix
    errors, the stated std as without)."""
    from pyins import inertial_sensor, sim, transform
    rng = np.random.default_rng(seed)
    t, speed, heading, grade_deg, pitch, roll = car_motion(duration_s, rate_hz, rng)
    h, c = np.deg2rad(heading), np.cos(np.deg2rad(grade_deg))
    vel_axle = speed[:, None] * np.column_stack([np.cos(h) * c, np.sin(h) * c, -np.sin(np.deg2rad(grade_deg))])
    rph = np.column_stack([roll, pitch, heading])
    axle, _ = sim.generate_imu(t, LLA0, rph, vel_axle, sensor_type="rate")
    imu_traj = transform.translate_trajectory(axle, IMU_V_M * FLU)
    traj, inc = sim.generate_imu(t, imu_traj[["lat", "lon", "alt"]].to_numpy(), rph, sensor_type="increment")
    gyro_model = inertial_sensor.EstimationModel(
        bias_sd=0.01 * DEG_H, noise=0.001 * np.pi / 180 / 60, bias_walk=0.005 * DEG_H * np.sqrt(2 / 3600),
        scale_misal_sd=np.full((3, 3), 5 * np.pi / 180 / 3600) + np.diag(np.full(3, 10e-6 - 5 * np.pi / 180 / 3600)))
    accel_model = inertial_sensor.EstimationModel(
        bias_sd=10e-6 * 9.80665, noise=0.003 / 60, bias_walk=5e-6 * 9.80665 * np.sqrt(2 / 3600),
        scale_misal_sd=np.full((3, 3), 5 * np.pi / 180 / 3600) + np.diag(np.full(3, 20e-6 - 5 * np.pi / 180 / 3600)))
    prng = np.random.RandomState(seed)
    inc = inc if ideal else inertial_sensor.apply_imu_parameters(
        inc, "increment", inertial_sensor.Parameters.from_EstimationModel(gyro_model, prng),
        inertial_sensor.Parameters.from_EstimationModel(accel_model, prng))
    k = np.arange(0, t.size, int(round(rate_hz / gnss_rate_hz)))[1:]
    antenna = transform.translate_trajectory(traj.iloc[k], ANTENNA_B_M * FLU)[["lat", "lon", "alt"]].to_numpy()
    white = rng.normal(size=(k.size, 3)) * [WHITE_H_M, WHITE_H_M, WHITE_V_M]
    err_enu = white + _gauss_markov(k.size, 1 / gnss_rate_hz, np.array([CORR_H_M, CORR_H_M, CORR_V_M]), CORR_TAU_S, rng)
    err_enu *= 0.0 if ideal else 1.0
    fix_lla = transform.perturb_lla(antenna, err_enu[:, [1, 0, 2]] * [1, 1, -1])
    std = np.hypot([WHITE_H_M, WHITE_H_M, WHITE_V_M], [CORR_H_M, CORR_H_M, CORR_V_M]) * (0.5 if stated == "optimistic" else 1.0)
    return CarSurvey(t, inc[["gyro_x", "gyro_y", "gyro_z"]].to_numpy(), inc[["accel_x", "accel_y", "accel_z"]].to_numpy(),
                     traj[["lat", "lon", "alt"]].to_numpy(), traj[["VN", "VE", "VD"]].to_numpy(),
                     t[k], fix_lla, np.broadcast_to(std, (k.size, 3)).copy(), err_enu)


def write_bag(s: CarSurvey, path: Path, imu_axes_flu: bool = True) -> None:
    """The survey as a rosbag2 folder (MCAP storage) by rosbags' writer: ``/imu/data``
    (sensor_msgs/msg/Imu, REP-103 F-L-U unless not ``imu_axes_flu``: pyins' F-R-D as they are;
    rates = increments / interval) and ``/gnss/fix`` (sensor_msgs/msg/NavSatFix, status GBAS =
    RTK fixed, diagonal ENU covariance)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    dt = np.diff(s.t_s, prepend=s.t_s[0] - (s.t_s[1] - s.t_s[0]))[:, None]
    flip = FLU if imu_axes_flu else np.ones(3)
    gyro, accel = s.gyro_inc_frd / dt * flip, s.accel_inc_frd / dt * flip
    v3, q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    stamp = lambda ns: T["std_msgs/msg/Header"](  # noqa: E731
        stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9), frame_id="imu_link")
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        ci = w.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=store)
        cg = w.add_connection("/gnss/fix", "sensor_msgs/msg/NavSatFix", typestore=store)
        ns_imu = EPOCH_NS + np.rint(s.t_s * 1e9).astype(np.int64)
        ns_fix = EPOCH_NS + np.rint(s.fix_t_s * 1e9).astype(np.int64)
        fixes = iter(zip(ns_fix.tolist(), s.fix_lla, s.fix_std_enu_m))
        nxt = next(fixes, None)
        for ns, g, a in zip(ns_imu.tolist(), gyro, accel):
            msg = T["sensor_msgs/msg/Imu"](
                header=stamp(ns), orientation=q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=np.r_[-1.0, np.zeros(8)],
                angular_velocity=v3(x=g[0], y=g[1], z=g[2]), angular_velocity_covariance=np.zeros(9),
                linear_acceleration=v3(x=a[0], y=a[1], z=a[2]), linear_acceleration_covariance=np.zeros(9))
            w.write(ci, ns + 500_000, store.serialize_cdr(msg, "sensor_msgs/msg/Imu"))
            while nxt is not None and nxt[0] <= ns:
                fns, lla, std = nxt
                fix = T["sensor_msgs/msg/NavSatFix"](
                    header=stamp(fns), status=T["sensor_msgs/msg/NavSatStatus"](status=2, service=1),
                    latitude=lla[0], longitude=lla[1], altitude=lla[2],
                    position_covariance=np.diag(std**2).ravel(), position_covariance_type=2)
                w.write(cg, fns + 30_000_000, store.serialize_cdr(fix, "sensor_msgs/msg/NavSatFix"))
                nxt = next(fixes, None)


def write_text(s: CarSurvey, folder: Path) -> Path:
    """The survey as KF-GINS-style text (``imu.txt``: t [s], F-R-D angle increments [rad],
    velocity increments [m/s]; ``gnss.txt``: t, lat, lon, h, std N, E, D [m]) and the import
    mapping for ``trackfusion import`` (``axes: frd``, increment units). Returns the mapping."""
    import yaml
    folder.mkdir(parents=True, exist_ok=True)
    np.savetxt(folder / "imu.txt", np.column_stack([s.t_s, s.gyro_inc_frd, s.accel_inc_frd]), fmt="%.17g")
    std = s.fix_std_enu_m
    np.savetxt(folder / "gnss.txt", np.column_stack([s.fix_t_s, s.fix_lla, std[:, 1], std[:, 0], std[:, 2]]), fmt="%.17g")
    mapping = {
        "imu": {"file": "imu.txt", "delimiter": "whitespace", "header": False, "time": {"column": 0, "unit": "s"},
                "gyro": {"columns": [1, 2, 3], "unit": "rad"}, "accel": {"columns": [4, 5, 6], "unit": "m/s"},
                "axes": "frd"},
        "gnss": {"file": "gnss.txt", "delimiter": "whitespace", "header": False, "time": {"column": 0, "unit": "s"},
                 "latitude": {"column": 1}, "longitude": {"column": 2}, "height": {"column": 3},
                 "sigma_enu": {"columns": [5, 4, 6], "unit": "m"}, "fix_quality": 4}}
    (folder / "import.yaml").write_text(yaml.safe_dump(mapping))
    return folder / "import.yaml"


def truth_errors_m(s: CarSurvey, trajectory: dict, origin: dict) -> np.ndarray:
    """(K,3) ENU position errors [m] of a trajectory table (t_s, e_m, n_m, u_m in n at
    ``origin``) against the true IMU origin, interpolated at its times (cubic Hermite in n)."""
    from trackfusion import geodesy
    from trackfusion.evaluation.errors_series import hermite_interpolate
    pos = geodesy.geodetic_to_n(s.lla_imu[:, 0], s.lla_imu[:, 1], s.lla_imu[:, 2], geodesy.Origin(**origin))
    # the local ENU velocity (km from the origin its direction in n differs by ~1e-4 rad: < 0.01 mm here)
    vel_n = s.vel_ned[:, [1, 0, 2]] * [1, 1, -1]
    ref = hermite_interpolate(s.t_s, pos, vel_n, trajectory["t_s"])
    return np.column_stack([trajectory[c] for c in ("e_m", "n_m", "u_m")]) - ref
