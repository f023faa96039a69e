"""A plainly written strapdown integrator, independent of the simulator, used as a test oracle.

Integrates interval-mean IMU samples (the mean over (t_{k-1}, t_k]) in the
Earth-fixed frame n:  dR/dt = R [w_ib - R^T Omega]x,
dv/dt = R f - 2 Omega x v + gamma(r),  dr/dt = v.
Second order: the attitude is advanced by the rotation vector of the mean rate,
the specific force is rotated with the mid-interval attitude, and gravity and
Coriolis are taken at the predicted mid-interval state.
"""

import numpy as np



def _rodrigues(phi):
    angle = np.linalg.norm(phi)
    K = np.array([[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]])
    if angle < 1e-12:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + np.sin(angle) / angle * K + (1 - np.cos(angle)) / angle**2 * K @ K


A_M, F = 6378137.0, 1 / 298.257223563
B_M, E2 = A_M * (1 - F), F * (2 - F)
EP2 = E2 / (1 - E2)


def _gravity(r_n, origin, R_en0, r0_e):
    """Normal gravity in n from a closed-form (Bowring) latitude; Somigliana in its original form."""
    x, y, z = R_en0 @ r_n + r0_e
    p = np.hypot(x, y)
    beta = np.arctan2(z * A_M, p * B_M)
    lat = np.arctan2(z + EP2 * B_M * np.sin(beta) ** 3, p - E2 * A_M * np.cos(beta) ** 3)
    lon = np.arctan2(y, x)
    N = A_M / np.sqrt(1 - E2 * np.sin(lat) ** 2)
    h = p / np.cos(lat) - N
    c2, s2 = np.cos(lat) ** 2, np.sin(lat) ** 2
    g0 = (A_M * 9.7803253359 * c2 + B_M * 9.8321849378 * s2) / np.sqrt(A_M**2 * c2 + B_M**2 * s2)
    m = 7.292115e-5**2 * A_M**2 * B_M / 3.986004418e14
    g = g0 * (1 - 2 / A_M * (1 + F + m - 2 * F * s2) * h + 3 * h**2 / A_M**2)
    up_e = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    return -g * (R_en0.T @ up_e)


def integrate(t_s, gyro, accel, r0, v0, R0, origin):
    """Return positions (N, 3) at t_s given the state (r0, v0, R0) at t_s[0]; samples 1.. are used."""
    lat0, lon0 = np.radians(origin.lat_deg), np.radians(origin.lon_deg)
    omega = 7.292115e-5 * np.array([0.0, np.cos(lat0), np.sin(lat0)])
    R_en0 = np.array([[-np.sin(lon0), -np.sin(lat0) * np.cos(lon0), np.cos(lat0) * np.cos(lon0)],
                      [np.cos(lon0), -np.sin(lat0) * np.sin(lon0), np.cos(lat0) * np.sin(lon0)],
                      [0.0, np.cos(lat0), np.sin(lat0)]])
    N0 = A_M / np.sqrt(1 - E2 * np.sin(lat0) ** 2)
    r0_e = np.array([(N0 + origin.h_m) * np.cos(lat0) * np.cos(lon0),
                     (N0 + origin.h_m) * np.cos(lat0) * np.sin(lon0),
                     (N0 * (1 - E2) + origin.h_m) * np.sin(lat0)])
    r, v, R = np.array(r0, float), np.array(v0, float), np.array(R0, float)
    out = np.empty((len(t_s), 3))
    out[0] = r
    for k in range(1, len(t_s)):
        dt = t_s[k] - t_s[k - 1]
        w_nb = gyro[k] - R.T @ omega  # Earth rate removed with the start attitude (changes slowly)
        dR = _rodrigues(w_nb * dt)
        R_half = R @ _rodrigues(0.5 * w_nb * dt)
        r_mid = r + 0.5 * v * dt
        g = _gravity(r_mid, origin, R_en0, r0_e)
        v_mid_pred = v + 0.5 * dt * (R_half @ accel[k] + g - 2 * np.cross(omega, v))
        a_n = R_half @ accel[k] - 2 * np.cross(omega, v_mid_pred) + g
        v_new = v + a_n * dt
        r = r + 0.5 * (v + v_new) * dt
        v = v_new
        R = R @ dR
        out[k] = r
    return out
