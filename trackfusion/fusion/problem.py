"""What the smoother is given: sensor data already in ``n`` and on the IMU clock, the trolley
geometry and the settings. Pure data; :mod:`trackfusion.pipeline` builds it from a log."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .. import geodesy
from ..geodesy import Origin
from ..rotations import R_from_ypr
from ..sensors.types import GnssData, ImuData, InclinometerData, OdometerData
from .preintegration import ImuNoise
from .settings import FactorSettings, KeyframeSettings, SmootherSettings

if TYPE_CHECKING:  # (the readings' home is registration/)
    from ..registration.readings import PrismReadings


@dataclass(frozen=True)
class TrolleyFrame:
    """Where things sit on the vehicle (the pipeline's ``vehicle:``, trackfusion/vehicles.py).

    R_vb (3,3): mounting rotation ``b`` to ``v``; lever_arm_imu_v (3,) [m]: IMU origin in ``v``
    (``v``'s origin is the point of zero lateral and vertical velocity: on a trolley midway
    between the reference-rail wheel contacts); wheelbase_m [m] (0 for a road vehicle);
    odometer_wheel: ``"rear"`` or ``"front"`` reference-rail wheel; kind: ``trolley``,
    ``rail-vehicle`` or ``road-vehicle``; odometer_point_v (3,) [m] or None: where the odometer
    measures in ``v``, when not a reference-rail wheel (a road vehicle).
    """

    R_vb: np.ndarray
    lever_arm_imu_v: np.ndarray
    wheelbase_m: float
    odometer_wheel: str = "rear"
    kind: str = "trolley"
    odometer_point_v: np.ndarray | None = None

    @classmethod
    def from_angles(cls, mounting_ypr_deg, lever_arm_imu_v_m, wheelbase_m: float,
                    odometer_wheel: str = "rear", kind: str = "trolley",
                    odometer_point_v=None) -> "TrolleyFrame":
        """From mounting (yaw, pitch, roll) [deg] of ``b`` in ``v``."""
        y, p, r = np.radians(np.asarray(mounting_ypr_deg, dtype=float))
        point = None if odometer_point_v is None else np.asarray(odometer_point_v, dtype=float)
        return cls(R_from_ypr(y, p, r), np.asarray(lever_arm_imu_v_m, dtype=float), float(wheelbase_m),
                   odometer_wheel, kind, point)

    def lever_arm_b(self, point_v: np.ndarray) -> np.ndarray:
        """Vector (3,) [m] in ``b`` from the IMU origin to a point given in ``v``."""
        return self.R_vb.T @ (np.asarray(point_v, dtype=float) - self.lever_arm_imu_v)

    @property
    def nhc_lever_arm_b(self) -> np.ndarray:
        """IMU to the trolley frame's origin (the point whose lateral/vertical speed is zero)."""
        return self.lever_arm_b(np.zeros(3))

    @property
    def wheel_lever_arm_b(self) -> np.ndarray:
        """IMU to the odometer wheel's rail contact (or to ``odometer_point_v``)."""
        if self.odometer_point_v is not None:
            return self.lever_arm_b(self.odometer_point_v)
        sign = -1.0 if self.odometer_wheel == "rear" else 1.0
        return self.lever_arm_b(np.array([sign * 0.5 * self.wheelbase_m, 0.0, 0.0]))

    @property
    def axis_b(self) -> np.ndarray:
        """The vehicle's x axis (forward; along the rails) in ``b``."""
        return self.R_vb.T @ np.array([1.0, 0.0, 0.0])


@dataclass
class GnssFixes:
    """GNSS antenna positions in ``n``: t_s (N,) [s, IMU clock]; pos_n (N,3) [m];
    cov_n (N,3,3) [m^2]; fix_quality (N,) int (4 fixed, 5 float)."""

    t_s: np.ndarray
    pos_n: np.ndarray
    cov_n: np.ndarray
    fix_quality: np.ndarray
    lever_arm_b: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def from_data(cls, data: GnssData, origin: Origin, lever_arm_b, clock_offset_s: float = 0.0) -> "GnssFixes":
        """Fixes of a log (geodetic, ENU covariance at each fix) in ``n`` (covariance rotated from
        the fix's local ENU into ``n``); ``t_s - clock_offset_s`` puts them on the IMU clock."""
        pos_n = geodesy.geodetic_to_n(data.lat_deg, data.lon_deg, data.h_m, origin)
        R = geodesy.R_n_local(pos_n, origin)
        cov_n = R @ data.cov_enu_m2 @ np.swapaxes(R, -1, -2)
        return cls(data.t_s - clock_offset_s, pos_n, cov_n, np.asarray(data.fix_quality),
                   np.asarray(lever_arm_b, dtype=float))


@dataclass
class FusionProblem:
    """Everything the smoother needs (all times on the IMU clock, positions in ``n``).

    imu_gyro_bias_deg_per_h: the specification's turn-on gyro bias (decides gyrocompassing).
    static_intervals_s: [(start, end)] detected static periods.
    """

    imu: ImuData
    imu_noise: ImuNoise
    imu_gyro_bias_deg_per_h: float
    origin: Origin
    trolley: TrolleyFrame
    static_intervals_s: list[tuple[float, float]]
    factors: FactorSettings = field(default_factory=FactorSettings)
    keyframes: KeyframeSettings = field(default_factory=KeyframeSettings)
    smoother: SmootherSettings = field(default_factory=SmootherSettings)
    odometer: OdometerData | None = None
    gnss: GnssFixes | None = None
    inclinometer: InclinometerData | None = None
    prisms: PrismReadings | None = None  # total-station prism readings
