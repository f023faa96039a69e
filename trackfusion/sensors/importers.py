"""Import CSV / text sensor logs into the project's MCAP raw log, and export a log back to CSV.

``trackfusion import MAPPING.yaml --out log.mcap`` reads one text file per sensor as the mapping
YAML says (docs/import.md): which file, its delimiter, comment character, header line, which
column holds the time and in which unit, and which columns hold each quantity in which unit.
Values are converted to the log's SI units (docs/log_format.md) and written with
:func:`~trackfusion.sensors.mcap_log.write_log` (atomically: a bad file leaves nothing behind).

Every problem raises one line naming the file and, for data, the line and column:
``imu.csv: line 17, column 'gx': 'abc' is not a number``; mapping problems name the YAML and
the field (:class:`ConfigError`).

``trackfusion export LOG --out DIR`` writes the inverse: one CSV per sensor in SI units, the
metadata as JSON and an ``import.yaml`` that imports them again to the same log content.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any, Union

import numpy as np
import yaml
from pydantic import Field, ValidationError, model_validator

from ..errors import ConfigError, SensorDataError, config_error_from_validation
from ..strict import StrictModel
from ..yamlio import load_yaml
from .fileio import read_json, write_json_atomic, write_text_atomic
from .imu_axes import axes_matrix, check_imu_frame, rates_from_increments, to_body
from .mcap_log import read_log, write_log
from .types import GaugeData, GnssData, ImuData, InclinometerData, OdometerData, SensorLog, TotalStationData

G0_MPS2 = 9.80665
#: Factor from each accepted unit to the log's SI unit, per kind of quantity.
UNITS: dict[str, dict[str, float]] = {
    "time": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9},
    "rate": {"rad/s": 1.0, "deg/s": math.pi / 180.0, "deg/h": math.pi / 180.0 / 3600.0},
    "accel": {"m/s^2": 1.0, "g": G0_MPS2, "mg": G0_MPS2 * 1e-3},
    # per-sample increments (an integrating IMU's delta-angle and delta-velocity over its interval)
    "gyro_increment": {"rad": 1.0, "deg": math.pi / 180.0},
    "accel_increment": {"m/s": 1.0},
    "length": {"m": 1.0, "mm": 1e-3, "km": 1e3},
    "angle": {"rad": 1.0, "deg": math.pi / 180.0, "gon": math.pi / 200.0},
    "geo_angle": {"deg": 1.0, "rad": 180.0 / math.pi},
    "area": {"m^2": 1.0, "mm^2": 1e-6},
}

Column = Union[str, int]


class Col(StrictModel):
    """One column (header name, or 0-based index when the file has no header) and its unit."""

    column: Column
    unit: str | None = None


class Cols(StrictModel):
    """Several columns (x, y, z or the 9 covariance entries row by row) sharing one unit."""

    columns: list[Column]
    unit: str | None = None


class FileSpec(StrictModel):
    """The text layout common to every sensor file."""

    file: str
    delimiter: str = Field(",", description="one character, or 'whitespace'")
    comment: str | None = "#"
    header: bool = True
    skip_rows: int = Field(0, ge=0, description="lines skipped before the header / first row")
    time: Col

    @model_validator(mode="after")
    def _check(self):
        if self.delimiter != "whitespace" and len(self.delimiter) != 1:
            raise ValueError("delimiter: one character or 'whitespace'")
        return self


class ImuSpec(FileSpec):
    """``gyro``/``accel``: rates (rad/s, deg/s, deg/h; m/s^2, g, mg) or per-sample increments
    (rad, deg; m/s); ``axes``: where the sensor's x, y, z point (three letters from F/B, L/R,
    U/D, or a 3x3 signed permutation ``C_b_s``; sensors/imu_axes.py)."""

    gyro: Cols
    accel: Cols
    axes: str | tuple[tuple[int, int, int], tuple[int, int, int], tuple[int, int, int]] = "flu"

    @model_validator(mode="after")
    def _axes(self):
        axes_matrix(self.axes)
        return self


class OdometerSpec(FileSpec):
    distance: Col
    ticks: Col | None = None
    ticks_per_m: float | None = Field(None, gt=0, description="ticks = round(distance * ticks_per_m) when no column")


class GnssSpec(FileSpec):
    latitude: Col
    longitude: Col
    height: Col
    covariance: Cols | None = None
    sigma_enu: Cols | None = None
    fix_quality: Col | int = 4


class TotalStationSpec(FileSpec):
    horizontal_angle: Col
    zenith_angle: Col
    slope_distance: Col
    prism_id: Col | str = "prism"


class InclinometerSpec(FileSpec):
    roll: Col
    pitch: Col


class GaugeSpec(FileSpec):
    gauge: Col


class ImportMapping(StrictModel):
    """The mapping YAML: one section per sensor present; paths relative to the YAML's folder."""

    metadata: str | None = None
    survey: dict[str, Any] | None = None
    imu: ImuSpec | None = None
    odometer: OdometerSpec | None = None
    gnss: GnssSpec | None = None
    total_stations: dict[str, TotalStationSpec] = {}
    inclinometer: InclinometerSpec | None = None
    gauge: GaugeSpec | None = None


# --- reading one text file ---------------------------------------------------------------------------

class _Table:
    """A text file's numeric columns, read with one C-level parse (``np.loadtxt``); on failure
    or a non-finite value, a line-by-line scan names the first bad line and column."""

    def __init__(self, base: Path, spec: FileSpec):
        self.path = base / spec.file if not Path(spec.file).is_absolute() else Path(spec.file)
        self.spec = spec
        if not self.path.is_file():
            raise SensorDataError(f"{self.path}: file not found")
        self.delimiter = None if spec.delimiter == "whitespace" else spec.delimiter
        self.names, self.first_data_line = self._header()

    def _split(self, line: str) -> list[str]:
        if self.delimiter is None:
            return line.split()
        return [f.strip().strip('"') for f in next(csv.reader([line], delimiter=self.delimiter))]

    def _is_data(self, line: str) -> bool:
        s = line.strip()
        return bool(s) and not (self.spec.comment and s.startswith(self.spec.comment))

    def _header(self) -> tuple[list[str] | None, int]:
        """Column names (None without header) and the 0-based line index where data may start."""
        with self.path.open("r", encoding="utf-8", errors="replace") as fh:
            for i, line in enumerate(fh):
                if i < self.spec.skip_rows or not self._is_data(line):
                    continue
                return (self._split(line), i + 1) if self.spec.header else (None, i)
        raise SensorDataError(f"{self.path}: no {'header line' if self.spec.header else 'data rows'}")

    def index(self, column: Column) -> int:
        if self.names is None:
            if not isinstance(column, int) or column < 0:
                raise SensorDataError(f"{self.path}: column {column!r}: the file has no header, "
                                      "give a 0-based column index")
            return column
        if isinstance(column, int):
            return column
        if column not in self.names:
            raise SensorDataError(f"{self.path}: column {column!r} not in the header ({', '.join(self.names)})")
        return self.names.index(column)

    def label(self, idx: int) -> str:
        return repr(self.names[idx]) if self.names and idx < len(self.names) else str(idx)

    def _data_lines(self):
        with self.path.open("r", encoding="utf-8", errors="replace") as fh:
            for i, line in enumerate(fh):
                if i >= self.first_data_line and self._is_data(line):
                    yield i + 1, line

    def _locate(self, idx: list[int]) -> SensorDataError:
        """The first line with a missing, unreadable or non-finite value among columns ``idx``."""
        for lineno, line in self._data_lines():
            fields = self._split(line)
            for j in idx:
                if j >= len(fields):
                    return SensorDataError(f"{self.path}: line {lineno}, column {self.label(j)}: missing "
                                           f"(the line has {len(fields)} fields)")
                try:
                    v = float(fields[j])
                except ValueError:
                    return SensorDataError(f"{self.path}: line {lineno}, column {self.label(j)}: "
                                           f"{fields[j]!r} is not a number")
                if not math.isfinite(v):
                    return SensorDataError(f"{self.path}: line {lineno}, column {self.label(j)}: {fields[j]!r} "
                                           "is not finite")
        return SensorDataError(f"{self.path}: unreadable (no single bad value found)")

    def numbers(self, columns: list[Column]) -> np.ndarray:
        """(N, len(columns)) float array of those columns."""
        idx = [self.index(c) for c in columns]
        try:
            data = np.loadtxt(self.path, delimiter=self.delimiter, comments=self.spec.comment,
                              skiprows=self.first_data_line, usecols=idx, ndmin=2, dtype=float, encoding="utf-8",
                              quotechar='"' if self.delimiter else None)
        except ValueError:
            raise self._locate(idx) from None
        if data.shape[0] == 0:
            raise SensorDataError(f"{self.path}: no data rows")
        if not np.all(np.isfinite(data)):
            raise self._locate(idx)
        return data

    def texts(self, column: Column) -> np.ndarray:
        """(N,) object array of one text column."""
        j = self.index(column)
        out = []
        for lineno, line in self._data_lines():
            fields = self._split(line)
            if j >= len(fields):
                raise SensorDataError(f"{self.path}: line {lineno}, column {self.label(j)}: missing")
            out.append(fields[j])
        return np.array(out, dtype=object)

    def line_of_row(self, row: int) -> int:
        for k, (lineno, _) in enumerate(self._data_lines()):
            if k == row:
                return lineno
        return -1


def _factor(table: _Table, kind: str, unit: str | None, what: str) -> float:
    units = UNITS[kind]
    if unit is None:
        return 1.0  # SI by default
    if unit not in units:
        raise SensorDataError(f"{table.path}: {what}: unknown unit {unit!r} (use {', '.join(units)})")
    return units[unit]


def _read(table: _Table, fields: dict[str, tuple[Col | Cols, str, int]]) -> dict[str, np.ndarray]:
    """One parse of the file for every field: name -> (column spec, unit kind, width; 0 = one
    column). Returns name -> SI array ((N,) or (N, width)); ``t_s`` (the file's time column,
    checked to increase) is always included."""
    specs = {"t_s": (table.spec.time, "time", 0), **fields}
    columns, where = [], {}
    for name, (spec, kind, width) in specs.items():
        cols = [spec.column] if isinstance(spec, Col) else list(spec.columns)
        if width and len(cols) != width:
            raise SensorDataError(f"{table.path}: {name}: needs {width} columns, got {len(cols)}")
        where[name] = slice(len(columns), len(columns) + len(cols))
        columns += cols
    data = table.numbers(columns)
    out = {name: (data[:, where[name]] if width else data[:, where[name].start])
           * (_factor(table, kind, spec.unit, name) if kind else 1.0)
           for name, (spec, kind, width) in specs.items()}
    bad = np.flatnonzero(np.diff(out["t_s"]) <= 0)
    if bad.size:
        raise SensorDataError(f"{table.path}: line {table.line_of_row(int(bad[0]) + 1)}, column "
                              f"{table.label(table.index(table.spec.time.column))}: time does not increase")
    return out


def _whole(table: _Table, values: np.ndarray, column: Column, what: str) -> np.ndarray:
    if not np.array_equal(values, np.rint(values)):
        row = int(np.flatnonzero(values != np.rint(values))[0])
        raise SensorDataError(f"{table.path}: line {table.line_of_row(row)}, column {table.label(table.index(column))}: "
                              f"{what} must be whole numbers")
    return values.astype(np.int64)


def _imu_kind(table: _Table, spec: Cols, rate: str, increment: str, what: str) -> str:
    """The unit kind of a gyro/accel column set: ``rate`` or, for an increment unit, ``increment``."""
    if spec.unit is None or spec.unit in UNITS[rate]:
        return rate
    if spec.unit in UNITS[increment]:
        return increment
    raise SensorDataError(f"{table.path}: {what}: unknown unit {spec.unit!r} (use {', '.join(UNITS[rate])}; "
                          f"per-sample increments: {', '.join(UNITS[increment])})")


def _imu(base: Path, s: ImuSpec) -> ImuData:
    """The IMU file's samples as rates in the body frame ``b`` (increments divided by each
    sample's interval; the declared ``axes`` turned into FLU)."""
    t = _Table(base, s)
    gyro_kind = _imu_kind(t, s.gyro, "rate", "gyro_increment", "gyro")
    accel_kind = _imu_kind(t, s.accel, "accel", "accel_increment", "accel")
    f = _read(t, {"gyro": (s.gyro, gyro_kind, 3), "accel": (s.accel, accel_kind, 3)})
    gyro, accel = f["gyro"], f["accel"]
    if gyro_kind != "rate":
        gyro = rates_from_increments(f["t_s"], gyro)
    if accel_kind != "accel":
        accel = rates_from_increments(f["t_s"], accel)
    c_b_s = axes_matrix(s.axes)
    imu = to_body(ImuData(f["t_s"], gyro, accel), c_b_s)
    check_imu_frame(imu, str(t.path), c_b_s, "imu.axes")
    return imu


def _odometer(base: Path, s: OdometerSpec) -> OdometerData:
    t = _Table(base, s)
    fields = {"distance": (s.distance, "length", 0)}
    if s.ticks is not None:
        fields["ticks"] = (s.ticks, "", 0)
    elif s.ticks_per_m is None:
        raise SensorDataError(f"{t.path}: odometer: give a 'ticks' column or 'ticks_per_m'")
    f = _read(t, fields)
    ticks = (_whole(t, f["ticks"], s.ticks.column, "ticks") if s.ticks is not None
             else np.rint(f["distance"] * s.ticks_per_m).astype(np.int64))
    return OdometerData(f["t_s"], f["distance"], ticks)


def _gnss(base: Path, s: GnssSpec) -> GnssData:
    t = _Table(base, s)
    fields = {"lat": (s.latitude, "geo_angle", 0), "lon": (s.longitude, "geo_angle", 0),
              "h": (s.height, "length", 0)}
    if s.covariance is not None:
        fields["cov"] = (s.covariance, "area", 9)
    elif s.sigma_enu is not None:
        fields["sigma"] = (s.sigma_enu, "length", 3)
    else:
        raise SensorDataError(f"{t.path}: gnss: give 'covariance' (9 columns, ENU) or 'sigma_enu' (3 columns)")
    if isinstance(s.fix_quality, Col):
        fields["q"] = (s.fix_quality, "", 0)
    f = _read(t, fields)
    cov = f["cov"].reshape(-1, 3, 3) if "cov" in f else np.einsum("ni,ij->nij", f["sigma"] ** 2, np.eye(3))
    q = (_whole(t, f["q"], s.fix_quality.column, "fix_quality") if "q" in f
         else np.full(f["t_s"].size, s.fix_quality, np.int64))
    return GnssData(f["t_s"], f["lat"], f["lon"], f["h"], cov, q)


def _total_station(base: Path, sid: str, s: TotalStationSpec) -> TotalStationData:
    t = _Table(base, s)
    f = _read(t, {"hz": (s.horizontal_angle, "angle", 0), "v": (s.zenith_angle, "angle", 0),
                  "sd": (s.slope_distance, "length", 0)})
    prism = (t.texts(s.prism_id.column) if isinstance(s.prism_id, Col)
             else np.array([s.prism_id] * f["t_s"].size, dtype=object))
    return TotalStationData(sid, f["t_s"], f["hz"], f["v"], f["sd"], prism)


def _inclinometer(base: Path, s: InclinometerSpec) -> InclinometerData:
    t = _Table(base, s)
    f = _read(t, {"roll": (s.roll, "angle", 0), "pitch": (s.pitch, "angle", 0)})
    return InclinometerData(f["t_s"], f["roll"], f["pitch"])


def _gauge(base: Path, s: GaugeSpec) -> GaugeData:
    t = _Table(base, s)
    f = _read(t, {"gauge": (s.gauge, "length", 0)})
    return GaugeData(f["t_s"], f["gauge"])


def load_mapping(path: str | Path) -> tuple[ImportMapping, Path]:
    """Read and validate a mapping YAML; returns it and the folder its paths start from."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: mapping file not found")
    data = load_yaml(p, "mapping file")
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: a mapping must be a mapping of sensor sections")
    try:
        return ImportMapping.model_validate(data), p.resolve().parent
    except ValidationError as exc:
        raise config_error_from_validation(exc, str(p)) from None


def import_log(mapping_path: str | Path) -> SensorLog:
    """Read every file a mapping YAML names into a :class:`SensorLog` (SI units, see module doc)."""
    m, base = load_mapping(mapping_path)
    log = SensorLog()
    if m.metadata is not None:
        log.metadata = read_json(base / m.metadata)
    if m.survey is not None:
        log.metadata["survey"] = {**log.metadata.get("survey", {}), **m.survey}
    from .fused import survey_epoch_ns
    survey_epoch_ns(log.metadata, str(mapping_path))  # a bad survey.epoch_utc refused here, not at a run's end
    if m.imu is not None:
        log.imu = _imu(base, m.imu)
    if m.odometer is not None:
        log.odometer = _odometer(base, m.odometer)
    if m.gnss is not None:
        log.gnss = _gnss(base, m.gnss)
    for sid, spec in m.total_stations.items():
        log.total_stations[sid] = _total_station(base, sid, spec)
    if m.inclinometer is not None:
        log.inclinometer = _inclinometer(base, m.inclinometer)
    if m.gauge is not None:
        log.gauge = _gauge(base, m.gauge)
    if log.imu is None and log.odometer is None and log.gnss is None and not log.total_stations:
        raise ConfigError(f"{mapping_path}: no sensor section (imu, odometer, gnss, total_stations, ...)")
    return log


def import_to_mcap(mapping_path: str | Path, out_path: str | Path, force: bool = False) -> SensorLog:
    """Import the files of a mapping YAML and write them as an MCAP raw log at ``out_path``
    (checked first, :class:`~trackfusion.outdir.OutputFile`: an existing file trackfusion did not
    write is replaced only with ``force``)."""
    from ..outdir import OutputFile
    target = OutputFile(out_path, force, inputs=[mapping_path], command="trackfusion import")
    target.check()
    log = import_log(mapping_path)
    with target.writing() as path:
        write_log(path, log)
    return log


# --- export --------------------------------------------------------------------------------------------

def _write_csv(path: Path, names: list[str], columns: list[np.ndarray], text: np.ndarray | None = None) -> None:
    """CSV with a header; floats as shortest exact repr, so values round-trip bit-exactly."""
    rows = zip(*[c.tolist() for c in columns])
    lines = [",".join(names + (["prism_id"] if text is not None else []))]
    if text is None:
        lines += [",".join(map(repr, r)) for r in rows]
    else:
        for r, s in zip(rows, text.tolist()):
            if "," in s or '"' in s or "\n" in s:
                raise SensorDataError(f"{path}: prism id {s!r} holds a delimiter or quote")
            lines.append(",".join(map(repr, r)) + "," + s)
    write_text_atomic(path, "\n".join(lines) + "\n")


def export_csv(log_path: str | Path, out_dir: str | Path, force: bool = False) -> list[str]:
    """Write each sensor of a raw log as CSV (SI units, ``t_s`` in seconds), its metadata as
    ``metadata.json`` and an ``import.yaml`` mapping them into the folder ``out_dir`` (checked,
    locked, staged and renamed: :class:`~trackfusion.outdir.OutputFolder`); returns the file names."""
    from ..outdir import OutputFolder
    folder = OutputFolder(out_dir, force, inputs=[log_path], command="trackfusion export")
    with folder.locked():
        log = read_log(log_path)
        with folder.staging() as stage:
            _export_log(log, log_path, stage)
            return sorted(p.name for p in stage.iterdir())


def _export_log(log: SensorLog, log_path: str | Path, out: Path) -> None:
    mapping: dict[str, Any] = {"metadata": "metadata.json"}
    xyz = lambda p: [f"{p}_{a}" for a in "xyz"]  # noqa: E731
    if log.imu is not None:
        d = log.imu
        _write_csv(out / "imu.csv", ["t_s", *xyz("gyro"), *xyz("accel")],
                   [d.t_s, *d.gyro_radps.T, *d.accel_mps2.T])
        mapping["imu"] = {"file": "imu.csv", "time": {"column": "t_s", "unit": "s"}, "gyro": {"columns": xyz("gyro"), "unit": "rad/s"},
                          "accel": {"columns": xyz("accel"), "unit": "m/s^2"}}
    if log.odometer is not None:
        d = log.odometer
        _write_csv(out / "odometer.csv", ["t_s", "distance_m", "ticks"], [d.t_s, d.distance_m, d.ticks])
        mapping["odometer"] = {"file": "odometer.csv", "time": {"column": "t_s", "unit": "s"}, "distance": {"column": "distance_m", "unit": "m"},
                               "ticks": {"column": "ticks"}}
    if log.gnss is not None:
        d = log.gnss
        cov = [f"cov_{i}{j}" for i in "enu" for j in "enu"]
        _write_csv(out / "gnss.csv", ["t_s", "lat_deg", "lon_deg", "h_m", *cov, "fix_quality"],
                   [d.t_s, d.lat_deg, d.lon_deg, d.h_m, *d.cov_enu_m2.reshape(-1, 9).T, d.fix_quality])
        mapping["gnss"] = {"file": "gnss.csv", "time": {"column": "t_s", "unit": "s"}, "latitude": {"column": "lat_deg", "unit": "deg"},
                           "longitude": {"column": "lon_deg", "unit": "deg"}, "height": {"column": "h_m", "unit": "m"},
                           "covariance": {"columns": cov, "unit": "m^2"}, "fix_quality": {"column": "fix_quality"}}
    stations = {}
    for sid, d in sorted(log.total_stations.items()):
        name = f"total_station_{sid}.csv"
        _write_csv(out / name, ["t_s", "hz_rad", "zenith_rad", "slope_m"],
                   [d.t_s, d.horizontal_angle_rad, d.zenith_angle_rad, d.slope_distance_m], text=d.prism_id)
        stations[sid] = {"file": name, "time": {"column": "t_s", "unit": "s"}, "horizontal_angle": {"column": "hz_rad", "unit": "rad"},
                         "zenith_angle": {"column": "zenith_rad", "unit": "rad"},
                         "slope_distance": {"column": "slope_m", "unit": "m"}, "prism_id": {"column": "prism_id"}}
    if stations:
        mapping["total_stations"] = stations
    if log.inclinometer is not None:
        d = log.inclinometer
        _write_csv(out / "inclinometer.csv", ["t_s", "roll_rad", "pitch_rad"], [d.t_s, d.roll_rad, d.pitch_rad])
        mapping["inclinometer"] = {"file": "inclinometer.csv", "time": {"column": "t_s", "unit": "s"},
                                   "roll": {"column": "roll_rad", "unit": "rad"},
                                   "pitch": {"column": "pitch_rad", "unit": "rad"}}
    if log.gauge is not None:
        _write_csv(out / "gauge.csv", ["t_s", "gauge_m"], [log.gauge.t_s, log.gauge.gauge_m])
        mapping["gauge"] = {"file": "gauge.csv", "time": {"column": "t_s", "unit": "s"}, "gauge": {"column": "gauge_m", "unit": "m"}}
    write_json_atomic(out / "metadata.json", log.metadata)
    write_text_atomic(out / "import.yaml", f"# written by 'trackfusion export {log_path}' (docs/import.md)\n"
                      + yaml.safe_dump(mapping, sort_keys=False))
