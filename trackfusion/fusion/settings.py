"""Smoother settings: which factors are used and their noise (the ``factors``, ``keyframes``,
``static`` and ``smoother`` sections of a pipeline YAML; docs/pipeline.md).

Every model refuses unknown keys; units are in the key names. A factor section may be
written as ``true``/``false`` instead of a mapping (defaults, switched on or off).
"""

from __future__ import annotations

import importlib.util
from typing import Any, Literal

import numpy as np

from pydantic import Field, field_validator, model_validator

from ..registration.timesync import TimeSyncSettings
from ..strict import StrictModel


class _Factor(StrictModel):
    enabled: bool = True

    @model_validator(mode="before")
    @classmethod
    def _bool_shorthand(cls, data: Any) -> Any:
        return {"enabled": data} if isinstance(data, bool) else data


class ImuFactorSettings(_Factor):
    """Preintegrated IMU factor between keyframes; ``earth_rate`` and ``gravity_per_position`` may be
    switched off only to demonstrate what they do (tests)."""

    earth_rate: bool = True
    gravity_per_position: bool = True


class ZuptSettings(_Factor):
    """Zero velocity, and zero rotation and displacement between consecutive keyframes, on
    detected static intervals."""

    sigma_velocity_mm_per_s: float = Field(0.2, gt=0)
    sigma_displacement_mm: float = Field(0.01, gt=0)
    sigma_rate_deg_per_h: float = Field(0.1, gt=0)


class NhcSettings(_Factor):
    """Zero lateral and vertical velocity (in ``v``) of the point midway between the
    reference-rail wheel contacts (the trolley frame's origin).

    ``sigma_mm_per_s`` holds for both axes unless ``sigma_lateral_mm_per_s`` /
    ``sigma_vertical_mm_per_s`` are given; docs/pipeline.md ("Choosing the NHC sigma") derives
    them from the trolley's wheelbase, speed and the track's irregularity (track/nhc_noise.py).
    """

    sigma_mm_per_s: float = Field(1.0, gt=0)
    sigma_lateral_mm_per_s: float | None = Field(None, gt=0)
    sigma_vertical_mm_per_s: float | None = Field(None, gt=0)

    def sigmas_mps(self) -> np.ndarray:
        """(lateral, vertical) sigma [m/s], shape (2,): the rows of the NHC residual."""
        lateral = self.sigma_lateral_mm_per_s or self.sigma_mm_per_s
        vertical = self.sigma_vertical_mm_per_s or self.sigma_mm_per_s
        return np.array([lateral, vertical]) * 1e-3


class WheelPathSettings(_Factor):
    """The rear reference-rail wheel passes through the points the front one touched, one
    wheelbase of odometer distance later (lateral and vertical; fusion/wheel_path.py,
    docs/wheel_path.md). Used when there is an odometer; ``sigma_mm`` per axis; one factor at
    every ``keyframe_step``-th keyframe (the front wheel's; 2: the hour's CPU cost within 2 s).
    Off by default; the pipelines the simulator writes for GNSS + odometer surveys and
    configs/open-track-gnss.yaml and curved-line.yaml switch it on; runs smoothed in chunks leave
    it out (fusion/chunks.py: the hand-over does not carry it yet; docs/wheel_path.md)."""

    enabled: bool = False
    sigma_mm: float = Field(0.01, gt=0)
    keyframe_step: int = Field(2, ge=1)


class OdometerFactorSettings(_Factor):
    """Distance increments between keyframes with a scale-error state per ``scale_segment_s``
    (docs/error_models.md, "Odometer scale"): ``scale_sigma_ppm`` the prior on the scale error
    at the start (a wheel's diameter tolerance and wear: up to 1 %); the scale a random walk of
    ``scale_random_walk_ppm_per_sqrt_h`` plus a drift (temperature, wear) at a rate with a state
    per segment: ``scale_rate_sigma_ppm_per_h`` the prior on the rate (null: no drift, the scale
    a random walk alone), ``scale_rate_random_walk_ppm_per_h_per_sqrt_h`` how fast the rate may
    change (a steady drift costs nothing)."""

    sigma_mm: float = Field(0.05, gt=0)
    scale_sigma_ppm: float = Field(10000.0, gt=0)
    scale_rate_sigma_ppm_per_h: float | None = Field(3000.0, gt=0)
    scale_rate_random_walk_ppm_per_h_per_sqrt_h: float = Field(10.0, gt=0)
    scale_random_walk_ppm_per_sqrt_h: float = Field(20.0, gt=0)
    scale_segment_s: float = Field(10.0, gt=0)
    huber_k: float = Field(3.0, gt=0)
    gross_error_threshold_m: float = Field(0.01, gt=0)
    gross_error_window: int = Field(8, ge=4)


class GnssFactorSettings(_Factor):
    """Antenna position with lever arm; Huber loss; fixes whose normalised residual exceeds
    ``gate_chi2`` (3 degrees of freedom) after a solve are rejected and the graph solved again.

    The fix error is modelled as white noise plus a correlated part (first-order Gauss-Markov,
    ``correlated_sigma_*_mm`` per horizontal / vertical axis, ``correlation_time_s``: multipath,
    residual atmosphere) estimated as a state per fix. The white part is the reported
    covariance times ``covariance_scale`` minus the correlated variance, at least
    ``min_sigma_mm``. Set both correlated sigmas to 0 to treat fixes as white.

    ``estimate_white_noise``: the white part's variance factor (horizontal, vertical) is
    estimated from the residuals after each solve (with at least 30 fixes), applied when
    significantly different from 1 (the white sigma at least ``min_sigma_mm``), and the gate
    decided on the estimated noise
    (fusion/gnss_noise.py, docs/noise_estimation.md).

    ``estimate_time_constant``: the correlated part's time constant estimated by the survey's
    marginal likelihood after the solve, and the survey solved again with it when the
    likelihood-ratio test (95 %) rejects ``correlation_time_s`` (fusion/gnss_time_constant.py; off by
    default: it costs 17-33 eliminations of the whole graph, and a second solve when applied).
    """

    covariance_scale: float = Field(1.0, gt=0)
    correlated_sigma_h_mm: float = Field(8.0, ge=0)
    correlated_sigma_v_mm: float = Field(15.0, ge=0)
    correlation_time_s: float = Field(300.0, gt=0)
    min_sigma_mm: float = Field(2.0, gt=0)
    huber_k: float = Field(2.0, gt=0)
    gate_chi2: float = Field(21.1, gt=0)
    accept_float: bool = True
    estimate_white_noise: bool = True
    estimate_time_constant: bool = False


class InclinometerFactorSettings(_Factor):
    """Roll and pitch of ``v`` measured by an inclinometer (seed 004)."""

    sigma_mrad: float = Field(0.1, gt=0)


class TotalStationFactorSettings(_Factor):
    """Prism positions from robotic total stations (docs/total_stations.md).

    ``registration``: ``graph`` estimates each station's small rotation, translation, clock
    offset and (``estimate_clock_drift``) drift in the factor graph, with priors from the
    instrument specification (sensors.total_stations); ``seed`` applies seed 003's registration
    (X-Z rotation about the station centre and translation, cross-track translation) to the
    point clouds before fusion and holds the stations fixed (clock offset still refined);
    ``none`` fixes the set-ups as given. Huber loss on the whitened residual (``huber_k``);
    after a solve, readings whose normalised squared residual (3 degrees of freedom) exceeds
    ``gate_chi2`` are rejected and the graph solved again (30: a false alarm in about 1.4e-6 of
    good readings, ~0.05 an hour at 10 Hz and two stations); ``mislock_min_run`` or more such
    readings of one station with at most ``mislock_max_gap`` accepted readings between them form
    a mis-lock (the station tracking something else), and the whole run is rejected.
    ``time_sync``: registration/timesync.py. The stations are estimated jointly with the whole
    trajectory.
    """

    enabled: bool = False
    registration: Literal["graph", "seed", "none"] = "graph"
    estimate_clock_drift: bool = True
    huber_k: float = Field(2.0, gt=0)
    gate_chi2: float = Field(30.0, gt=0)
    mislock_min_run: int = Field(5, ge=2)
    mislock_max_gap: int = Field(3, ge=0)
    clock_offset_sigma_s: float = Field(0.05, gt=0)
    time_sync: TimeSyncSettings = TimeSyncSettings()


class NoiseEstimationSettings(_Factor):
    """Each measurement group's noise (NHC, odometer, wheel path, GNSS correlated part, every
    total station, inclinometer) estimated from its residuals after the solve, with the
    configured sigma as prior, applied where it differs significantly, and reported
    (fusion/noise_components.py, docs/noise_estimation.md)."""

    enabled: bool = True


class FactorSettings(StrictModel):
    imu: ImuFactorSettings = ImuFactorSettings()
    zupt: ZuptSettings = ZuptSettings()
    nhc: NhcSettings = NhcSettings()
    wheel_path: WheelPathSettings = WheelPathSettings()
    odometer: OdometerFactorSettings = OdometerFactorSettings()
    gnss: GnssFactorSettings = GnssFactorSettings()
    inclinometer: InclinometerFactorSettings = InclinometerFactorSettings()
    total_stations: TotalStationFactorSettings = TotalStationFactorSettings()
    noise_estimation: NoiseEstimationSettings = NoiseEstimationSettings()


class KeyframeSettings(StrictModel):
    """``spacing_s``: time between keyframes (the wheel-path factor lets them be sparser:
    docs/solver_speed.md); ``bias_segment_s``: length of the segments over which one IMU bias
    state holds (random walk between segments; fusion/preintegration.py)."""

    spacing_s: float = Field(0.1, gt=0, le=5.0)
    bias_segment_s: float = Field(300.0, gt=0)


class StaticSettings(StrictModel):
    """Static-interval detection (moving standard deviations over ``window_s``).

    The gyro and accelerometer thresholds default to four times the IMU's per-sample white
    noise (from its specification), but at least 0.01 deg/s and 0.005 m/s^2.
    """

    window_s: float = Field(0.5, gt=0)
    gyro_std_deg_per_s: float | None = Field(None, gt=0)
    accel_std_mps2: float | None = Field(None, gt=0)
    max_odometer_speed_mps: float = Field(0.001, gt=0)
    min_duration_s: float = Field(2.0, gt=0)

    def thresholds(self, gyro_arw_deg_per_sqrt_h: float, accel_vrw_mps_per_sqrt_h: float,
                   rate_hz: float) -> tuple[float, float]:
        """(gyro [deg/s], accel [m/s^2]) thresholds for an IMU of this noise and rate."""
        root = np.sqrt(rate_hz) / 60.0  # per-sample sigma = density [unit/sqrt(h)] / 60 * sqrt(rate)
        gyro = self.gyro_std_deg_per_s or max(0.01, 4.0 * gyro_arw_deg_per_sqrt_h * root)
        accel = self.accel_std_mps2 or max(0.005, 4.0 * accel_vrw_mps_per_sqrt_h * root)
        return gyro, accel


#: default data [s] a chunk is solved with beyond its join (``smoother.overlap_s``): with 120 s
#: the 5 m lateral error within 15 min of the join of a 2 h survey was 1.5 x the one batch's
#: (0.08 against 0.05 mm: the chunk's heading at the join, held by the next, saw too little of
#: what came after); with 600 s it is the batch's (docs/long_runs.md)
CHUNK_OVERLAP_S = 600.0

#: ``smoother.chunk_s: auto`` (the default): the chunk [s] of a run too long for one batch
AUTO_CHUNK_S = 3600.0
#: with ``auto``, a run of at most this many keyframes and :data:`AUTO_ONE_BATCH_MAX_S` is one
#: batch (the keyframes an hour and 600 s of 0.1 s keyframes always were): a run's memory grows
#: with its keyframes; 2 h of 0.2 s keyframes at 500 Hz (34 401) peaked at 3.5 GB for the process
#: and its forked children, where the 10 h survey in 6 600 s chunks took 4.2 GB (docs/long_runs.md)
AUTO_ONE_BATCH_KEYFRAMES = 42_000
#: the longest run [s] that ``auto`` solves as one batch
AUTO_ONE_BATCH_MAX_S = 7200.0


class SmootherSettings(StrictModel):
    """Gauss-Newton iterations (stop when the cost falls by less than ``relative_tolerance``)
    and the spacing of the marginal covariances behind the sigma columns.

    ``chunk_s`` / ``overlap_s``: runs longer than ``chunk_s + overlap_s`` are smoothed in
    overlapping chunks (fusion/chunks.py), so memory is bounded by the chunk; ``chunk_s: null``
    solves any run as one batch (memory grows with its keyframes: about 1.7 GB an hour of 0.2 s
    keyframes at 500 Hz). ``auto`` (the default): a run of up to 2 h is one batch where its
    keyframes allow (:meth:`one_batch_up_to_s`), a longer one goes in chunks of an hour.
    ``overlap_s`` null: :data:`CHUNK_OVERLAP_S`, at most half the chunk (:attr:`chunk_overlap_s`).

    ``workers``: with ``part_s``, the local processes the parts of each step are solved in
    (trackfusion/parallel.py: the same numbers with any count); the run's densification takes
    one fewer forked processes (at least one, fusion/densify_forked.py: the same rows); null: 1.
    The sigma columns' 600 s parts of a longer run are dealt to the CPUs this process may use,
    whatever ``workers`` says (fusion/partitioned.py ``part_marginal_covariances``: the same bits).
    Nothing here depends on the CPU count: the same log gives the same trajectory anywhere.

    ``part_s``: each Gauss-Newton step is solved in time parts of this duration
    (fusion/partitioned.py: the one-batch answer, to rounding; at least 10 s); null: in one piece,
    but for the converging steps of a run longer than 600 s, which are solved in the sigma
    columns' 600 s parts on the CPUs this process may use (the same step; their reductions serve
    the sigmas: docs/solver_speed.md, "The converging step in the sigma parts").

    ``engine``: where the parts are solved: ``local`` (``workers`` processes of this machine) or
    ``dask`` (the workers of the Dask scheduler at ``address``, else of a ``distributed.LocalCluster``
    of ``workers`` processes; needs ``part_s`` and the extra ``[distributed]``). The same numbers.

    ``step_tolerance_mm``: the iterations also stop when the correction still to come, predicted
    from the rate at which the steps shrink, is below this (fusion/convergence.py); 0: off.
    """

    max_iterations: int = Field(10, ge=1)
    relative_tolerance: float = Field(1e-7, gt=0)
    step_tolerance_mm: float = Field(0.02, ge=0)
    marginal_step_s: float = Field(1.0, gt=0)
    chunk_s: float | Literal["auto"] | None = "auto"
    overlap_s: float | None = Field(None, gt=0)
    workers: int | None = Field(None, ge=1, le=16)
    part_s: float | None = Field(None, ge=10.0)
    engine: Literal["local", "dask"] = "local"
    address: str | None = None

    @model_validator(mode="after")
    def _dask_engine(self) -> "SmootherSettings":
        if self.address is not None and self.engine != "dask":
            raise ValueError("address: only with engine: dask")
        if self.engine == "dask":
            if self.part_s is None:
                raise ValueError("engine: dask needs part_s (the parts are what the Dask workers solve)")
            if importlib.util.find_spec("distributed") is None:
                raise ValueError("engine: dask: Dask is not installed (pip install 'trackfusion[distributed]')")
        return self

    @property
    def chunk_length_s(self) -> float | None:
        """The chunk [s] of a run smoothed in chunks: ``chunk_s``, :data:`AUTO_CHUNK_S` for ``auto``;
        None: every run is one batch."""
        return AUTO_CHUNK_S if self.chunk_s == "auto" else self.chunk_s

    @property
    def chunk_overlap_s(self) -> float:
        """The data [s] a chunk is solved with beyond its join: ``overlap_s``, else
        :data:`CHUNK_OVERLAP_S` or half the chunk when that is shorter."""
        if self.overlap_s is not None:
            return self.overlap_s
        length = self.chunk_length_s
        return min(CHUNK_OVERLAP_S, 0.5 * length) if length is not None else CHUNK_OVERLAP_S

    def one_batch_up_to_s(self, spacing_s: float) -> float | None:
        """The longest run [s] smoothed as one batch with keyframes ``spacing_s`` [s] apart; None:
        any. A written ``chunk_s``: the chunk and its overlap. ``auto``: that much with
        :data:`AUTO_CHUNK_S`, or :data:`AUTO_ONE_BATCH_KEYFRAMES` keyframes up to
        :data:`AUTO_ONE_BATCH_MAX_S` when longer (2 h of 0.2 s keyframes, 70 min of 0.1 s ones)."""
        length = self.chunk_length_s
        if length is None:
            return None
        written = length + self.chunk_overlap_s
        if self.chunk_s != "auto":
            return written
        return max(written, min(AUTO_ONE_BATCH_MAX_S, AUTO_ONE_BATCH_KEYFRAMES * spacing_s))

    @field_validator("chunk_s", mode="before")
    @classmethod
    def _chunk_length(cls, value: Any) -> Any:
        if value is None or value == "auto":
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 60.0 <= value < np.inf:
            raise ValueError("a duration of at least 60 s, auto or null")
        return value

    @model_validator(mode="after")
    def _overlap_inside_chunk(self) -> "SmootherSettings":
        length = self.chunk_length_s
        if length is not None and self.chunk_overlap_s >= length:
            raise ValueError(f"overlap_s ({self.chunk_overlap_s:g}) must be shorter than the chunk ({length:g} s)")
        return self
