"""Error hierarchy of trackfusion.

Every error the toolkit raises on purpose derives from :class:`TrackfusionError`.
The command line turns any of them into exit code 2 and one line naming the
file, field or record at fault (``str(error)``); a worker process that died
(:class:`WorkerDied`) gives exit code 1 and one line; anything else is an
internal error (exit code 1).
"""

from __future__ import annotations


class TrackfusionError(Exception):
    """Root of every deliberate trackfusion error (bad input, bad config, ...)."""


class GeodesyError(TrackfusionError):
    """Invalid geodetic input (latitude out of range, non-finite coordinate, ...)."""


class SensorDataError(TrackfusionError):
    """A sensor log or data file is unreadable or holds an invalid record."""


class ConfigError(TrackfusionError):
    """A pipeline, scenario or alignment configuration is invalid."""


class FusionError(TrackfusionError):
    """The factor-graph smoother cannot proceed with the given data."""


class RegistrationError(TrackfusionError):
    """Time synchronisation or station registration failed."""


class TrackGeometryError(TrackfusionError):
    """Track alignment or geometry computation got invalid input."""


class EvaluationError(TrackfusionError):
    """Evaluation input is invalid (empty, missing column, no overlap, ...)."""


class SimulationError(TrackfusionError):
    """A simulation scenario cannot be built as requested."""


class WorkerDied(RuntimeError):
    """A worker process (a forked child, a worker of the smoother's parts) ended without its
    answer: killed, out of memory. Not a fault of the input, so not a :class:`TrackfusionError`:
    the command line exits with code 1 and one line naming the work it was doing."""


def config_error_from_validation(exc, source: str) -> ConfigError:
    """A :class:`ConfigError` of one line naming ``source`` and the first invalid field path
    of a pydantic ``ValidationError`` (``source: imu.rate_hz: Input should be greater than 0``)."""
    err = exc.errors()[0]
    path = ".".join(str(p) if str(p).isprintable() else repr(p) for p in err["loc"]) or "(top level)"
    return ConfigError(f"{source}: {path}: {' '.join(str(err['msg']).split())}")


class ReportError(TrackfusionError):
    """The report cannot be written (missing run files, no browser for the PDF, ...)."""


class VisionError(TrackfusionError):
    """Camera-laser input is invalid (unreadable image, calibration set or file, ...)."""


class OutputError(TrackfusionError):
    """An output folder or file cannot or must not be written (a file where a folder is meant,
    not writable, holding files trackfusion did not write, locked by another run, ...)."""
