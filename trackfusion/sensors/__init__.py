"""Sensor data: types, MCAP raw-log and CSV result I/O, error models.

All file I/O of the toolkit (besides the report) lives in this subpackage.
"""
