"""The track geometry's file inputs and its step in a pipeline run (the I/O boundary of :mod:`.track`).

The core (:mod:`trackfusion.track`) takes data: a parsed tolerance mapping
(:func:`~trackfusion.track.geometry.parse_tolerances`), a LandXML file's bytes
(:func:`~trackfusion.track.landxml.parse_landxml`), an alignment mapping
(:meth:`~trackfusion.track.design.DesignAlignment.from_dict`). This module reads the files --
the design alignment (LandXML 1.2 or YAML) and the tolerance tables (package tables under
``trackfusion/data/tolerances`` or a YAML file) -- and joins the pipeline object with
:func:`~trackfusion.track.geometry.compute_geometry`.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from . import geodesy
from .errors import ConfigError
from .track.design import AlignmentConfig, DesignAlignment
from .track.geometry import GeometryResult, ToleranceCheck, compute_geometry, parse_tolerances, pitch_rate_v
from .track.landxml import parse_landxml
from .track.traces import TrajectoryOnTrack, TrolleyGeometry
from .yamlio import load_yaml, parse_yaml


def load_tolerances(name_or_path: str, base_dir: Path | None = None) -> tuple[str, list[ToleranceCheck]]:
    """A tolerance table by package name (``seed002-china``) or path (relative to ``base_dir``)."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml"):
        p = p if p.is_absolute() or base_dir is None else base_dir / p
        text, source = (p.read_text(encoding="utf-8") if p.is_file() else None), str(p)
    else:
        res = resources.files("trackfusion") / "data" / "tolerances" / f"{name_or_path}.yaml"
        text, source = (res.read_text(encoding="utf-8") if res.is_file() else None), f"tolerance table {name_or_path!r}"
    if text is None:
        known = sorted(q.name[:-5] for q in (resources.files("trackfusion") / "data" / "tolerances").iterdir()
                       if q.name.endswith(".yaml"))
        raise ConfigError(f"geometry.tolerances: {source} not found (package tables: {', '.join(known)})")
    return parse_tolerances(parse_yaml(text, source), source, name_or_path)


def read_landxml(path: str | Path) -> AlignmentConfig:
    """The design alignment of a LandXML 1.2 file (:func:`~trackfusion.track.landxml.parse_landxml`)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: unreadable design alignment ({exc.strerror or exc})") from None
    return parse_landxml(data, path)


def load_design(path: Path) -> DesignAlignment:
    """A design alignment, by the file's suffix: ``.xml`` / ``.landxml`` a LandXML 1.2 file
    (:func:`read_landxml`), ``.yaml`` / ``.yml`` a YAML file holding an ``alignment:``
    section (a scenario YAML works) or the alignment mapping itself."""
    suffix = path.suffix.lower()
    if suffix in (".xml", ".landxml"):
        return DesignAlignment(read_landxml(path))
    if suffix not in (".yaml", ".yml"):
        raise ConfigError(f"{path}: unknown design file type {suffix or '(no suffix)'!r} "
                          "(.xml / .landxml: LandXML 1.2; .yaml / .yml: YAML)")
    data = load_yaml(path, "design alignment")
    if isinstance(data, dict) and "alignment" in data:
        data = data["alignment"]
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: a design alignment must be a mapping (or hold an 'alignment:' section)")
    return DesignAlignment.from_dict(data, f"{path}: alignment")


def check_geometry_inputs(pipeline) -> None:
    """Fail early (before fusion) on a bad design file or tolerance table."""
    cfg = pipeline.config
    if cfg.inputs.design is not None:
        load_design(pipeline.path(cfg.inputs.design))
    if cfg.geometry.tolerances is not None:
        load_tolerances(cfg.geometry.tolerances, pipeline.base_dir)
    if cfg.geometry.chainage in ("projection", "curvature_matching") and cfg.inputs.design is None:
        raise ConfigError(f"{pipeline.source}: geometry.chainage: {cfg.geometry.chainage} needs inputs.design")


def geometry_for_run(pipeline, problem, res, dense, chainage_m: np.ndarray, gauge) -> GeometryResult | None:
    """:func:`compute_geometry` with the pieces of a pipeline run (``pipeline.run``); None when
    ``geometry.enabled`` is false."""
    cfg = pipeline.config
    g = cfg.geometry
    if not g.enabled:
        return None
    tf = problem.trolley
    trolley = TrolleyGeometry(tf.R_vb, tf.lever_arm_imu_v, tf.wheelbase_m, cfg.vehicle.reference_rail)
    # the IMU samples of the dense times (every sample, or every k-th one after chunked smoothing)
    gyro = problem.imu.gyro_radps[np.searchsorted(problem.imu.t_s, dense.t_s)]
    bias = np.column_stack([np.interp(dense.t_s, res.t_s, res.gyro_bias_radps[:, k]) for k in range(3)])
    pitch_rate = pitch_rate_v(dense.R_nb, gyro, bias, geodesy.earth_rate_n(problem.origin), tf.R_vb)
    design = load_design(pipeline.path(cfg.inputs.design)) if cfg.inputs.design else None
    tol = load_tolerances(g.tolerances, pipeline.base_dir) if g.tolerances else None
    traj = TrajectoryOnTrack(dense.t_s, dense.R_nb, dense.pos_n, chainage_m,
                             absolute_positions=problem.gnss is not None)
    return compute_geometry(traj, trolley, g, cfg.outputs.geometry_step_m, gauge, pitch_rate, design, tol)
