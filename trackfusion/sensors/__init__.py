"""Sensor data as real sensors give it: data types, datasheet models, raw-log (MCAP, ROS 2) and
CSV readers and writers, importers. Nothing here simulates (that is :mod:`trackfusion.simulation`).
"""
