"""trackfusion: railway track-geometry surveys from IMU, odometer, GNSS and total stations.

Conventions (every module follows them; names carry frames and units)
=====================================================================

Time
    Float seconds on the IMU clock ("survey time", ``t_s``). In a raw MCAP log
    ``log_time`` is integer nanoseconds of the *recording sensor's own* clock;
    total stations have their own clocks with an unknown offset
    (``t_station = t_imu + offset_s``).

Frames
    ``n``  local ENU tangent frame at the survey origin (lat0, lon0, h0),
           Earth-fixed. Every fused position is in ``n``.
    ``e``  ECEF, WGS-84.
    ``b``  IMU body frame: x forward, y left, z up.
    ``v``  trolley (vehicle) frame: x along the rails, y left, z up;
           ``R_vb`` is a small mounting rotation.
    ``t``  track frame at chainage s: x along the design centreline, y left,
           z normal to the running plane.
    ``k``  total station k's local level frame (z along its plumb line).

    ``R_nb`` maps b-coordinates to n (``x_n = R_nb @ x_b``). Quaternions are
    Hamilton ``(qw, qx, qy, qz)``, body to n. Euler angles are
    yaw, pitch, roll with ``R_nb = Rz(yaw) Ry(-pitch) Rx(roll)``
    (right-handed elementary rotations): yaw from east towards north,
    pitch positive nose up, roll positive left side up
    (:mod:`trackfusion.rotations`).

Units
    SI inside the code (m, s, rad, m/s^2); names and config keys carry units
    (``sigma_mm``, ``gyro_bias_instability_deg_per_h``). White noise is given
    as a root PSD (e.g. rad/s/sqrt(Hz)).

Physics
    ``n`` is Earth-fixed, so the Earth rate in ``n`` is constant; the specific
    force is ``f_n = dv_n/dt + 2 Omega_n x v_n - gamma_n(r)`` with WGS-84
    normal gravity ``gamma_n`` (gravitation plus centrifugal) of the point's
    own position, and the gyro measures ``w_ib_b = w_nb_b + R_bn Omega_n``.

Errors
    Every deliberate error derives from :class:`trackfusion.errors.TrackfusionError`;
    the command line maps them to exit code 2 with one line naming the
    file, field or record.
"""

from .errors import TrackfusionError

__all__ = ["TrackfusionError", "__version__"]
__version__ = "0.1.0"
