"""IMU datasheet model and grades: the noise, bias, scale, misalignment, quantisation and range
figures a data sheet states (1-sigma values; units in the field names).

Shared data: the simulator draws its errors from an :class:`ImuSpec`
(:mod:`trackfusion.simulation.imu`, which documents the error model), and the fusion reads the
same figures as its datasheet prior (``sensors.imu`` in the pipeline, checked against the data by
:mod:`trackfusion.fusion.imu_noise`). A flat-lined axis at the measurement range is refused by
``trackfusion run`` (:mod:`trackfusion.fusion.input_checks`).

Grades (:data:`IMU_GRADES`) follow the seeds: seed 002's navigation-grade IMU,
seed 003's at 500 Hz, seed 000's FOG and a tactical MEMS of seed 004's class.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from ..strict import StrictModel

DEG = np.pi / 180.0
ARCSEC = DEG / 3600.0
G0_MPS2 = 9.80665  #: standard gravity, for micro-g conversions [m/s^2]


class ImuSpec(StrictModel):
    """IMU sensor specification (1-sigma values; units in the names)."""

    rate_hz: float = Field(200.0, gt=0)
    gyro_arw_deg_per_sqrt_h: float = Field(0.001, ge=0)
    gyro_bias_deg_per_h: float = Field(0.01, ge=0)
    gyro_bias_instability_deg_per_h: float = Field(0.005, ge=0)
    gyro_bias_tau_s: float = Field(3600.0, gt=0)
    gyro_scale_ppm: float = Field(10.0, ge=0)
    gyro_misalignment_arcsec: float = Field(5.0, ge=0)
    gyro_quantum_rad: float = Field(0.0, ge=0)
    accel_vrw_mps_per_sqrt_h: float = Field(0.003, ge=0)
    accel_bias_ug: float = Field(10.0, ge=0)
    accel_bias_instability_ug: float = Field(5.0, ge=0)
    accel_bias_tau_s: float = Field(3600.0, gt=0)
    accel_scale_ppm: float = Field(20.0, ge=0)
    accel_misalignment_arcsec: float = Field(5.0, ge=0)
    accel_quantum_mps: float = Field(0.0, ge=0)
    gyro_range_deg_per_s: float = Field(400.0, gt=0)
    accel_range_mps2: float = Field(98.0665, gt=0)  # 10 g


#: Named grades: seed 002 (navigation, 200 Hz), seed 003 (navigation, 500 Hz),
#: seed 000 (FOG, 300 Hz), seed 004 class (tactical MEMS, 200 Hz). Measurement ranges (the seeds
#: are silent; typical data-sheet values of each class): navigation +-400 deg/s, +-10 g; FOG
#: +-500 deg/s, +-10 g; tactical MEMS +-450 deg/s, +-8 g.
IMU_GRADES: dict[str, ImuSpec] = {
    "navigation": ImuSpec(rate_hz=200.0, gyro_arw_deg_per_sqrt_h=0.001, gyro_bias_deg_per_h=0.01,
                          gyro_bias_instability_deg_per_h=0.005, accel_vrw_mps_per_sqrt_h=0.003,
                          accel_bias_ug=10.0, accel_bias_instability_ug=5.0),
    "navigation-500": ImuSpec(rate_hz=500.0, gyro_arw_deg_per_sqrt_h=0.001, gyro_bias_deg_per_h=0.01,
                              gyro_bias_instability_deg_per_h=0.005, accel_vrw_mps_per_sqrt_h=0.003,
                              accel_bias_ug=10.0, accel_bias_instability_ug=5.0),
    "fog": ImuSpec(rate_hz=300.0, gyro_arw_deg_per_sqrt_h=0.03, gyro_bias_deg_per_h=0.5,
                   gyro_bias_instability_deg_per_h=0.5, gyro_bias_tau_s=600.0, gyro_scale_ppm=50.0,
                   gyro_misalignment_arcsec=20.0, accel_vrw_mps_per_sqrt_h=0.02, accel_bias_ug=50.0,
                   accel_bias_instability_ug=20.0, accel_bias_tau_s=600.0, accel_scale_ppm=100.0,
                   accel_misalignment_arcsec=20.0, gyro_range_deg_per_s=500.0),
    "mems-tactical": ImuSpec(rate_hz=200.0, gyro_arw_deg_per_sqrt_h=0.15, gyro_bias_deg_per_h=5.0,
                             gyro_bias_instability_deg_per_h=2.0, gyro_bias_tau_s=300.0, gyro_scale_ppm=300.0,
                             gyro_misalignment_arcsec=100.0, accel_vrw_mps_per_sqrt_h=0.05,
                             accel_bias_ug=200.0, accel_bias_instability_ug=50.0, accel_bias_tau_s=300.0,
                             accel_scale_ppm=300.0, accel_misalignment_arcsec=100.0,
                             gyro_range_deg_per_s=450.0, accel_range_mps2=78.4532),  # 8 g
}
