"""The total stations' prism readings as the fusion takes them (:class:`PrismReadings`), and when a
station's pause in them is a tracking gap (:data:`PRISM_GAP_MIN_S`). Pure data; registration/survey.py
builds the readings, fusion/ consumes them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: a station's interval without readings is a gap when it lasts longer than this [s] (and
#: than ``fusion.faults.OUTAGE_FACTOR`` reading intervals)
PRISM_GAP_MIN_S = 1.0


@dataclass
class PrismReadings:
    """Total-station readings of the trolley prism, in ``n`` with the nominal (or resected)
    set-ups, on the IMU clock as synchronised (``t_imu = t_station - offset_s``), sorted by time.

    t_s (N,) [s]; pos_n (N,3) [m]; cov_n (N,3,3) [m^2] from the polar precision; station (N,)
    int index into ``station_ids`` (J,); station_pos_n (J,3) [m] instrument points (the centre
    of each station's rotation); lever_arm_b (3,) [m] IMU origin to the prism centre;
    prior_sigma (J,8) standard deviations of each station's correction state
    (fusion/factors.py ``STATION_STATE_DIM``: rotation [rad] (3, in ``n``), translation [m] (3),
    clock offset [s], clock drift [ppm]) about zero. flagged (N,) bool or None: readings left out
    of the fusion before it (the step check's mis-locks, registration/steps.py).
    """

    t_s: np.ndarray
    pos_n: np.ndarray
    cov_n: np.ndarray
    station: np.ndarray
    station_ids: list[str]
    station_pos_n: np.ndarray
    lever_arm_b: np.ndarray
    prior_sigma: np.ndarray
    flagged: np.ndarray | None = None

    def usable(self) -> np.ndarray:
        """Indices (M,) of the readings not flagged before the fusion."""
        return np.arange(self.t_s.size) if self.flagged is None else np.flatnonzero(~self.flagged)
