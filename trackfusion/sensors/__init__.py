"""Sensor data as real sensors give it: data types, datasheet models, raw-log (MCAP, ROS 2) and
CSV readers and writers, importers. Nothing here simulates (that is :mod:`trackfusion.simulation`).
"""


def __getattr__(name: str):
    """Transitional: the aiding-sensor simulators moved to :mod:`trackfusion.simulation.aiding`; this
    lazy alias serves importers not yet updated (listed in tests/test_layout.py) and goes once they are."""
    if name == "aiding":
        from ..simulation import aiding
        return aiding
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
