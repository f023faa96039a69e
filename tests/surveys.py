"""Shared simulation overrides of the end-to-end tests (``simulate_to_dir(..., overrides=...)``)."""

#: a short ``open-track-gnss`` survey: 30 s static, 240 m out at 3 m/s, 10 s static, 140 m back at 2 m/s
SHORT_OPEN_TRACK = ["motion.passes=1",
                    "motion.segments=[{hold_s: 30}, {move_to_m: 260, speed_mps: 3, accel_mps2: 0.4}, {hold_s: 10},"
                    " {move_to_m: 120, speed_mps: 2, accel_mps2: 0.4}]"]


def errors_against_truth(d, tab):
    """Position errors (N,3) [m] of a trajectory table ``tab`` against the survey folder ``d``'s
    truth.csv (Hermite-interpolated at its times), and the true chainage (N,) [m] there."""
    import numpy as np
    from trackfusion.evaluation.errors_series import hermite_interpolate
    from trackfusion.sensors.fileio import read_csv_table
    truth = read_csv_table(d / "truth.csv")
    pos_t = np.column_stack([truth[c] for c in ("e_m", "n_m", "u_m")])
    vel_t = np.column_stack([truth[c] for c in ("ve_mps", "vn_mps", "vu_mps")])
    ref = hermite_interpolate(truth["t_s"], pos_t, vel_t, tab["t_s"])
    return (np.column_stack([tab[c] for c in ("e_m", "n_m", "u_m")]) - ref,
            np.interp(tab["t_s"], truth["t_s"], truth["chainage_m"]))


def short_open_track_problem(d, seed, ideal=False):
    """The fusion problem of a short ``open-track-gnss`` survey (:data:`SHORT_OPEN_TRACK`)
    simulated with ``seed`` into folder ``d`` (``ideal``: without sensor errors), as ``trackfusion
    run`` builds it."""
    from trackfusion import pipeline as P
    from trackfusion.simulation.scenarios import simulate_to_dir
    simulate_to_dir("open-track-gnss", d, seed=seed, ideal=ideal, overrides=SHORT_OPEN_TRACK)
    pl = P.load_pipeline(d / "pipeline.yaml")
    log, _ = P._read(pl)
    return P.build_problem(pl, log, lambda _m: None)[0]
