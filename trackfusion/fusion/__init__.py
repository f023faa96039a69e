"""Fusion: factor-graph smoother (IMU preintegration, odometer, NHC, ZUPT, GNSS, prisms)."""
