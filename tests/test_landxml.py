"""LandXML 1.2 design alignments (track/landxml.py) against closed forms.

Oracles: Fresnel integrals for the clothoids (scipy.special.fresnel), circle and parabola
formulas for the arc and the vertical curve, the hand-written file
``tests/data/landxml_curve.xml`` (its geometry in its header comment) and the same design
written in trackfusion's YAML; round trips of random and scenario designs written as LandXML;
a run with either design. Bad files must give one-line errors naming file, line and element.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as hst
from scipy.special import fresnel

from trackfusion.cli import main
from trackfusion.errors import ConfigError
from trackfusion.sensors.fileio import read_csv_table
from trackfusion.simulation.config import available_scenarios, load_scenario
from trackfusion.simulation.scenarios import simulate_to_dir
from trackfusion.track.design import DesignAlignment
from trackfusion.geometry_inputs import load_design, read_landxml

CURVE_XML = Path(__file__).parent / "data" / "landxml_curve.xml"

# the hand-written file's geometry (its header comment)
E0, N0, TH0 = 1000.0, 2000.0, np.radians(60.0)
R, LS, LA = 300.0, 60.0, 90.0
A = np.sqrt(R * LS)
STA0 = 1000.0

YAML_DESIGN = {
    "horizontal": {"start_e_m": E0, "start_n_m": N0, "heading_deg": 60.0, "elements": [
        {"type": "tangent", "length_m": 100.0}, {"type": "clothoid", "length_m": LS},
        {"type": "arc", "length_m": LA, "radius_m": -R, "cant_mm": 90.0},
        {"type": "clothoid", "length_m": LS}, {"type": "tangent", "length_m": 100.0}]},
    "vertical": {"pvis": [{"chainage_m": 0.0, "u_m": 50.0}, {"chainage_m": 200.0, "u_m": 52.0, "curve_length_m": 80.0},
                          {"chainage_m": 410.0, "u_m": 49.9}]},
}


def _dir(th):
    return np.array([np.cos(th), np.sin(th)])


def _left(th):
    return np.array([-np.sin(th), np.cos(th)])


def _clothoid_xy(u, a):
    """Clothoid from zero curvature, local frame (x along the start tangent, y left): (..., 2)."""
    S, C = fresnel(u / (a * np.sqrt(np.pi)))
    return a * np.sqrt(np.pi) * np.stack([C, S], -1)


def _expected(s):
    """Hand-computed (E, N), heading, curvature, elevation and cant of the file's design at chainage s."""
    X, Y = _clothoid_xy(LS, A)
    p1 = np.array([E0, N0]) + 100 * _dir(TH0)
    th2 = TH0 - LS / (2 * R)
    p2 = p1 + X * _dir(TH0) - Y * _left(TH0)                     # right turn: mirrored clothoid
    centre = p2 - R * _left(th2)
    th3 = th2 - LA / R
    p3 = centre + R * _left(th3)
    th4 = th3 - LS / (2 * R)
    p4 = p3 + X * _dir(th4) + Y * _left(th4)                     # the exit clothoid seen from its end
    if s <= 100:
        xy, th, k = np.array([E0, N0]) + s * _dir(TH0), TH0, 0.0
    elif s <= 160:
        u = s - 100
        x, y = _clothoid_xy(u, A)
        xy, th, k = p1 + x * _dir(TH0) - y * _left(TH0), TH0 - u**2 / (2 * A**2), -u / A**2
    elif s <= 250:
        th = th2 - (s - 160) / R
        xy, k = centre + R * _left(th), -1 / R
    elif s <= 310:
        w = 310 - s
        x, y = _clothoid_xy(w, A)
        xy, th, k = p4 - x * _dir(th4) - y * _left(th4), th4 + w**2 / (2 * A**2), -w / A**2
    else:
        xy, th, k = p4 + (s - 310) * _dir(th4), th4, 0.0
    g1, g2, L = 0.01, -0.01, 80.0
    x = s - 160.0
    if s <= 160:
        z = 50 + g1 * s
    elif s >= 240:
        z = 49.9 - g2 * (410 - s)
    else:
        z = 52 + g1 * (x - L / 2) + (g2 - g1) / (2 * L) * x**2
    cant = float(np.interp(s, [100, 160, 250, 310], [0, 0.09, 0.09, 0]))  # outer rail of a right curve: left, +
    return xy, th, k, z, cant


STATIONS = [1000.0, 1050.0, 1130.0, 1160.0, 1180.0, 1200.0, 1230.0, 1280.0, 1310.0, 1360.0, 1410.0]


def test_hand_written_file_matches_the_closed_forms():
    design = load_design(CURVE_XML)
    assert design.length_m == pytest.approx(410.0, abs=1e-12)
    s = np.array(STATIONS) - STA0
    st = design.evaluate(s)
    for i, si in enumerate(s):
        xy, th, k, z, cant = _expected(si)
        # measured: 1.1e-11 m (the file's points are printed to 1e-10 m), 2.8e-14 rad
        assert np.hypot(*(st.pos_n[i, :2] - xy)) < 5e-11, si       # east, north: "N E" read the right way round
        assert abs(st.heading_rad[i] - th) < 2e-13, si
        assert abs(st.curvature_h_1pm[i] - k) < 1e-15, si
        assert abs(st.pos_n[i, 2] - z) < 1e-13, si
        assert abs(st.cant_m[i] - cant) < 1e-15, si
    # spot values by hand: the vertical curve's middle is the mid-ordinate (g2 - g1) L / 8 = 0.2 m below the PVI,
    # 20 m into it 52 - 0.01 * 20 - 2.5e-4 / 2 * 20^2; the full cant on the arc raises the left rail
    assert st.pos_n[STATIONS.index(1200.0), 2] == pytest.approx(51.8, abs=1e-12)
    assert st.pos_n[STATIONS.index(1180.0), 2] == pytest.approx(51.75, abs=1e-12)
    assert st.cant_m[STATIONS.index(1200.0)] == pytest.approx(0.09, abs=1e-15)
    assert np.degrees(st.cant_rad[STATIONS.index(1200.0)]) == pytest.approx(np.degrees(np.arcsin(0.09 / 1.5)))


def test_landxml_and_yaml_give_the_same_model(tmp_path):
    (tmp_path / "design.yaml").write_text(yaml.safe_dump({"alignment": YAML_DESIGN}))
    from_yaml, from_xml = load_design(tmp_path / "design.yaml"), load_design(CURVE_XML)
    assert from_xml.config.cant_base_m == pytest.approx(from_yaml.config.cant_base_m, abs=1e-12)
    s = np.linspace(0.0, 410.0, 4101)
    a, b = from_yaml.evaluate(s), from_xml.evaluate(s)
    assert np.abs(a.pos_n - b.pos_n).max() < 5e-11   # measured 1.0e-11 m (asked: 1e-9 m)
    for name in ("heading_rad", "slope_rad", "cant_m", "cant_rad", "curvature_h_1pm", "curvature_v_1pm"):
        assert np.abs(getattr(a, name) - getattr(b, name)).max() < 2e-13, name
    assert np.abs(a.R_nt - b.R_nt).max() < 2e-13


def _spiral_file(tmp_path, e0, n0, th0, a, length, rot, name="spiral.xml"):
    """A Line of 10 m and a clothoid of parameter a from INF, points computed from Fresnel integrals."""
    sign = 1.0 if rot == "ccw" else -1.0
    p1 = np.array([e0, n0]) + 10 * _dir(th0)
    x, y = _clothoid_xy(length, a)
    end = p1 + x * _dir(th0) + sign * y * _left(th0)
    defl = length**2 / (2 * a**2)
    pi = p1 + (x - y / np.tan(defl)) * _dir(th0)
    ne = lambda p: f"{p[1]:.10f} {p[0]:.10f}"  # noqa: E731
    body = f"""<Alignment name="S" staStart="0"><CoordGeom>
      <Line length="10"><Start>{n0:.10f} {e0:.10f}</Start><End>{ne(p1)}</End></Line>
      <Spiral length="{length}" radiusStart="INF" radiusEnd="{a * a / length!r}" rot="{rot}" spiType="clothoid">
        <Start>{ne(p1)}</Start><PI>{ne(pi)}</PI><End>{ne(end)}</End></Spiral>
      </CoordGeom>{_PROFILE}</Alignment>"""
    return _write(tmp_path / name, body)


_PROFILE = '<Profile><ProfAlign><PVI>0 0</PVI><PVI>1000 0</PVI></ProfAlign></Profile>'


def _write(path, alignment_xml, units='<Metric linearUnit="meter"/>', extra=""):
    path.write_text(f"""<?xml version="1.0"?>
<LandXML xmlns="http://www.landxml.org/schema/LandXML-1.2" version="1.2">
  <Units>{units}</Units>{extra}
  <Alignments>{alignment_xml}</Alignments>
</LandXML>
""")
    return path


@pytest.mark.parametrize("rot", ["ccw", "cw"])
def test_clothoid_end_point_and_tangent_match_fresnel(tmp_path, rot):
    a, length, th0 = 250.0, 120.0, np.radians(-35.0)
    design = load_design(_spiral_file(tmp_path, 500.0, -300.0, th0, a, length, rot))
    sign = 1.0 if rot == "ccw" else -1.0
    u = np.linspace(0.0, length, 25)
    st = design.evaluate(10.0 + u)
    start, th = st.pos_n[0, :2], st.heading_rad[0]
    assert np.hypot(*(start - (np.array([500.0, -300.0]) + 10 * _dir(th0)))) < 5e-11  # measured 1.3e-11 m
    assert th == pytest.approx(th0, abs=1e-12)
    local = _clothoid_xy(u, a)
    expected = start + local[:, :1] * _dir(th) + sign * local[:, 1:] * _left(th)
    assert np.abs(st.pos_n[:, :2] - expected).max() < 1e-12                        # measured 1.1e-13 m
    assert np.abs(st.heading_rad - (th + sign * u**2 / (2 * a**2))).max() < 1e-14   # tangent
    assert st.curvature_h_1pm[-1] == pytest.approx(sign * length / a**2, rel=1e-12)


def test_units_scale_lengths_stations_and_elevations(tmp_path):
    mm = """<Alignment name="mm" staStart="5000000"><CoordGeom>
      <Line length="100000"><Start>20000 10000</Start><End>120000 10000</End></Line></CoordGeom>
      <Profile><ProfAlign><PVI>5000000 1000</PVI><PVI>5100000 3000</PVI></ProfAlign></Profile>
      <Cant gauge="1435"><CantStation station="5000000" appliedCant="0" curvature="ccw"/>
        <CantStation station="5100000" appliedCant="100" curvature="ccw"/></Cant></Alignment>"""
    d = load_design(_write(tmp_path / "mm.xml", mm, units='<Metric linearUnit="millimeter"/>'))
    st = d.evaluate([0.0, 50.0, 100.0])
    assert d.length_m == pytest.approx(100.0)
    assert st.pos_n[:, :2] == pytest.approx(np.array([[10.0, 20.0], [10.0, 70.0], [10.0, 120.0]]))  # north-bound
    assert st.pos_n[:, 2] == pytest.approx([1.0, 2.0, 3.0])
    assert st.cant_m == pytest.approx([0.0, -0.05, -0.1])  # cant in mm; a left curve raises the right rail
    assert d.config.cant_base_m == pytest.approx(1.5)
    ft = mm.replace("mm", "ft").replace("1435", "4.708").replace('appliedCant="100"', 'appliedCant="4"')
    d = load_design(_write(tmp_path / "ft.xml", ft, units='<Imperial linearUnit="USSurveyFoot"/>'))
    assert d.length_m == pytest.approx(100000 * 1200 / 3937)
    assert d.evaluate([0.0]).pos_n[0, 1] == pytest.approx(20000 * 1200 / 3937)
    assert d.evaluate([d.length_m]).cant_m[0] == pytest.approx(-4 * 0.0254)  # inches


def test_adverse_cant_raises_the_inner_rail(tmp_path):
    text = CURVE_XML.read_text().replace('appliedCant="90" curvature="cw"/>',
                                         'appliedCant="90" curvature="cw" adverse="true"/>')
    d = load_design(_write_text(tmp_path / "adverse.xml", text))
    assert d.evaluate([200.0]).cant_m[0] == pytest.approx(-0.09)


def _write_text(path, text):
    path.write_text(text)
    return path


def _swap_ne(text):
    """Every point text 'N E' written 'E N' (the classic LandXML mistake)."""
    return re.sub(r"<(Start|End|PI|CgPoint name=\"CC1\")>(\S+) (\S+)<", r"<\1>\3 \2<", text)


BAD = [
    (lambda t: t[: len(t) // 2], "not well-formed XML"),
    (lambda t: t.replace("<LandXML ", "<Land ").replace("</LandXML>", "</Land>"), "not a LandXML file"),
    (lambda t: t.replace('encoding="UTF-8"', 'encoding="no-such"'), ":1: not readable XML (unknown encoding"),
    (lambda t: t.replace('linearUnit="meter"', 'linearUnit="furlong"'), "Metric: linearUnit='furlong'"),
    (lambda t: t.replace('spiType="clothoid">', 'spiType="cubic">', 1), "Spiral: spiType='cubic' is not supported"),
    (lambda t: t.replace('radius="300" rot="cw"', 'radius="300" rot="left"'), "Curve: rot='left'"),
    (lambda t: t.replace('radiusStart="INF"', 'radiusStart="0.0"'), "Spiral: radius 0 m must be at least 1 m"),
    (lambda t: t.replace("<PVI>1410 49.9</PVI>", "<PVI>1410 1e308</PVI>"), "PVI: station 1410 or elevation 1e+308"),
    (lambda t: t.replace("<PVI>1410 49.9</PVI>", "<PVI>1410 500</PVI>"), "PVI: the grade from the previous PVI"),
    (lambda t: t.replace('radius="300" rot="cw"', 'radius="300" rot="ccw"'), "Curve: its End point is 177.3121 m"),
    (lambda t: t.replace("1962.3247339099 1325.2354806113", "1962.3247339099 1325.2454806113"),
     "Curve: its Center point is"),
    (lambda t: t.replace('length="90" radius="300"', 'length="90.02" radius="300"'), "Spiral: staStart is 250.0000 m"),
    (lambda t: re.sub(r'(<(Line|Spiral|Curve)) staStart="\d+"', r"\1", t.replace(' length="410"', ""))
     .replace('length="90" radius="300"', 'length="90.02" radius="300"'), "Curve: its End point is 0.0200 m"),
    (_swap_ne, "Spiral: its End point is 3.9971 m"),
    (lambda t: t.replace('<Line staStart="1000" length="100">', '<Line staStart="1000">')  # moved 1 cm sideways
     .replace("<End>2086.6025403784 1050.0000000000</End>", "<End>2086.6075403784 1049.9913397460</End>"),
     "Spiral: its Start is 0.0100 m from the previous element's End (a gap)"),
    (lambda t: t.replace('<Line staStart="1310" length="100">', '<Line staStart="1310">')  # end turned by 1 mrad
     .replace("<End>2286.5806489154 1279.8962579960</End>", "<End>2286.6660489154 1279.8442279960</End>"),
     "Line: its start tangent turns 1.000 mrad from the previous element's end tangent (a kink)"),
    (lambda t: t.replace('<Line staStart="1310" length="100">', '<Line staStart="1311" length="100">'),
     "Line: staStart is 311.0000 m"),
    (lambda t: t.replace('length="410"', 'length="400"'), "Alignment 'Main': length 400.0000 m differs"),
    (lambda t: t.replace("<Feature code=\"note\"/>", "<IrregularLine/>"), "IrregularLine: an irregular line is not"),
    (lambda t: t.replace("<Profile name", "<StaEquation staAhead=\"1\" staInternal=\"1\"/><Profile name"),
     "StaEquation: station equations are not supported"),
    (lambda t: t.replace('<ParaCurve length="80">', '<UnsymParaCurve lengthIn="40" lengthOut="40">')
     .replace("</ParaCurve>", "</UnsymParaCurve>"), "UnsymParaCurve: is not supported"),
    (lambda t: t.replace('<ParaCurve length="80">', '<ParaCurve length="500">'), "overlaps a neighbouring PVI"),
    (lambda t: t.replace("<PVI>1410 49.9</PVI>", "<PVI>1410 abc</PVI>"), "PVI: text '1410 abc' is not"),
    (lambda t: t.replace("<ProfAlign", "<ProfAlignX").replace("</ProfAlign>", "</ProfAlignX>"),
     "exactly one Profile/ProfAlign"),
    (lambda t: t.replace('rotationPoint="insideRail"', 'rotationPoint="center"'), "rotationPoint='center'"),
    (lambda t: t.replace('appliedCant="90" curvature="cw"/>\n        <SpeedStation',
                         'appliedCant="90"/>\n        <SpeedStation'), "CantStation: missing attribute curvature"),
    (lambda t: t.replace('station="1310" appliedCant', 'station="1250" appliedCant'), "does not follow"),
    (lambda t: t.replace('station="1310" appliedCant', 'station="1420" appliedCant'),
     "CantStation: station 1420 lies off the alignment (1000 to 1410)"),
    (lambda t: t.replace("<Project ", '<CoordinateSystem epsgCode="25832"/><Project '), "epsgCode='25832'"),
    (lambda t: t.replace('<Alignments name="test">', '<Alignments name="test"><Alignment name="Other"/>'),
     "holds 2 Alignment elements ('Other', 'Main')"),
    (lambda t: t.replace('<Center pntRef="CC1"/>', '<Center pntRef="CC9"/>'), "pntRef='CC9' names no CgPoint"),
    (lambda t: t.replace("<Start>2000.0000000000 1000.0000000000</Start>", "<Start>2000.0 1000.0 5 6</Start>"),
     "point '2000.0 1000.0 5 6' is not"),
]


@pytest.mark.parametrize("change,message", BAD)
def test_bad_files_give_one_line_errors(tmp_path, change, message):
    path = _write_text(tmp_path / "bad.xml", change(CURVE_XML.read_text()))
    with pytest.raises(ConfigError) as exc:
        read_landxml(path)
    text = str(exc.value)
    assert message in text and "\n" not in text
    assert text.startswith(f"{path}:")


def test_spirals_without_pi_and_negative_inf_radii_are_read(tmp_path):
    """The schema requires a Spiral's PI; some writers leave it out (the start tangent is then the
    previous element's end tangent) or write -INF: the same model."""
    text = re.sub(r"<PI>[^<]*</PI>\s*<End>2137", "<End>2137", CURVE_XML.read_text())
    text = re.sub(r"<PI>[^<]*</PI>\s*<End>2234", "<End>2234", text).replace('radiusStart="INF"', 'radiusStart="-INF"')
    assert text.count("<PI>") == 1
    s = np.linspace(0.0, 410.0, 411)
    a, b = load_design(CURVE_XML).evaluate(s), load_design(_write_text(tmp_path / "nopi.xml", text)).evaluate(s)
    assert np.abs(a.pos_n - b.pos_n).max() < 5e-11


def test_error_names_the_line_of_the_element(tmp_path):
    text = CURVE_XML.read_text().replace('spiType="clothoid">', 'spiType="bloss">', 1)
    line = next(i for i, ln in enumerate(text.splitlines(), 1) if 'spiType="bloss"' in ln)  # where the tag opens
    with pytest.raises(ConfigError, match=rf"bad.xml:{line}: Spiral: spiType='bloss'"):
        read_landxml(_write_text(tmp_path / "bad.xml", text))


def test_small_errors_that_add_up_are_refused(tmp_path):
    """20 lines due east, each 4 mm longer than its length says: every element passes on its own
    (within 5 mm), the alignment rebuilt from the lengths ends 8 cm short."""
    lines = "".join(f'<Line length="99.996"><Start>0 {100 * k}</Start><End>0 {100 * (k + 1)}</End></Line>'
                    for k in range(20))
    path = _write(tmp_path / "drift.xml", f'<Alignment name="D"><CoordGeom>{lines}</CoordGeom>{_PROFILE}</Alignment>')
    with pytest.raises(ConfigError, match="Line: its (Start|End) point is 0.0[34]\\d+ m off the alignment rebuilt"):
        read_landxml(path)


def test_projected_grid_coordinates_are_refused(tmp_path):
    far = _spiral_file(tmp_path, 500_000.0, 5_400_000.0, 0.3, 250.0, 120.0, "cw", "utm.xml")
    with pytest.raises(ConfigError, match="projected-grid coordinates"):
        read_landxml(far)


def test_design_file_type_is_chosen_by_suffix(tmp_path):
    with pytest.raises(ConfigError, match=r"unknown design file type '\.txt'"):
        load_design(_write_text(tmp_path / "design.txt", CURVE_XML.read_text()))
    plain = CURVE_XML.read_text().replace('xmlns="http://www.landxml.org/schema/LandXML-1.2"', "")
    same = load_design(_write_text(tmp_path / "design.LandXML", plain))  # no namespace, upper-case suffix
    s = np.linspace(0, 410, 9)
    assert np.abs(same.evaluate(s).pos_n - load_design(CURVE_XML).evaluate(s).pos_n).max() == 0


def test_bad_landxml_design_exits_2_before_running(tmp_path, capsys):
    (tmp_path / "log.mcap").write_bytes(b"")
    _write_text(tmp_path / "design.xml", CURVE_XML.read_text().replace('spiType="clothoid">', 'spiType="cubic">', 1))
    p = {"inputs": {"log": "log.mcap", "design": "design.xml"},
         "trolley": {"wheelbase_m": 1.0, "lever_arm_imu_v_m": [0, 0, 0.2]},
         "sensors": {"imu": {"grade": "navigation"}}, "factors": {"gnss": False}}
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(p))
    assert main(["run", str(tmp_path / "p.yaml"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "design.xml:" in err and "spiType='cubic'" in err
    assert not (tmp_path / "out").exists()


def test_yaml_clothoid_end_radii_and_cant_stations():
    """The model's two additions the LandXML reader uses, written in YAML: a spiral-spiral curve
    (no arc) and cant given by stations."""
    cfg = {"horizontal": {"elements": [
        {"type": "tangent", "length_m": 50.0},
        {"type": "clothoid", "length_m": 40.0, "start_radius_m": float("inf"), "end_radius_m": 200.0},
        {"type": "clothoid", "length_m": 40.0, "start_radius_m": 200.0, "end_radius_m": float("inf")},
        {"type": "tangent", "length_m": 50.0}]},
        "cant_stations": [{"chainage_m": 50.0, "cant_mm": 0.0, "raised_rail": "right"},
                          {"chainage_m": 90.0, "cant_mm": 60.0, "raised_rail": "right"},
                          {"chainage_m": 130.0, "cant_mm": 0.0, "raised_rail": "right"}]}
    st = DesignAlignment.from_dict(cfg).evaluate([0.0, 70.0, 90.0, 110.0, 180.0])
    assert st.curvature_h_1pm == pytest.approx([0.0, 0.0025, 0.005, 0.0025, 0.0], abs=1e-15)
    assert st.heading_rad[-1] == pytest.approx(2 * 40.0 / (2 * 200.0), abs=1e-15)
    assert st.cant_m == pytest.approx([0.0, -0.03, -0.06, -0.03, 0.0], abs=1e-15)
    with pytest.raises(ConfigError, match="not both"):
        DesignAlignment.from_dict({**cfg, "horizontal": {"elements": [
            {"type": "arc", "length_m": 10.0, "radius_m": 100.0, "cant_mm": 50.0}]}})
    with pytest.raises(ConfigError, match="start_radius_m"):
        DesignAlignment.from_dict({"horizontal": {"elements": [
            {"type": "tangent", "length_m": 10.0, "start_radius_m": 100.0}]}})


# --- round trip: random designs written as LandXML (points from the model) read back the same ---------

def _as_landxml(design: DesignAlignment, path: Path, sta0: float) -> Path:
    """``design`` written as LandXML: element points from the model itself, printed exactly; cant
    at the element joints. A test helper: it checks the reader's parsing (N E order, rot, radii,
    stations, units) and fit over many geometries, not the geometry (the closed-form tests do)."""
    num = lambda x: repr(float(x))  # noqa: E731  (shortest exact text)
    ne = lambda p: f"{num(p[1])} {num(p[0])}"  # noqa: E731
    rad = lambda k: "INF" if k == 0 else num(1 / abs(k))  # noqa: E731
    parts, joints = [], []
    for e, s0 in zip(design.config.horizontal.elements, design.s_start):
        st = design.evaluate([s0, min(s0 + e.length_m, design.length_m)])
        p0, p1, h0, h1 = st.pos_n[0, :2], st.pos_n[1, :2], st.heading_rad[0], st.heading_rad[1]
        k0, k1 = st.curvature_h_1pm
        rot = "ccw" if (k0 + k1) > 0 else "cw"
        head = f'staStart="{num(sta0 + s0)}" length="{num(e.length_m)}"'
        if e.type == "tangent":
            parts.append(f"<Line {head}><Start>{ne(p0)}</Start><End>{ne(p1)}</End></Line>")
            continue
        d0, d1 = np.array([np.cos(h0), np.sin(h0)]), np.array([np.cos(h1), np.sin(h1)])
        t = ((p1 - p0)[0] * d1[1] - (p1 - p0)[1] * d1[0]) / (d0[0] * d1[1] - d0[1] * d1[0])
        pi = p0 + t * d0
        if e.type == "arc":
            centre = p0 + e.radius_m * _left(h0)
            parts.append(f'<Curve {head} radius="{num(abs(e.radius_m))}" rot="{rot}"><Start>{ne(p0)}</Start>'
                         f"<Center>{ne(centre)}</Center><End>{ne(p1)}</End><PI>{ne(pi)}</PI></Curve>")
        else:
            parts.append(f'<Spiral {head} radiusStart="{rad(k0)}" radiusEnd="{rad(k1)}" rot="{rot}" '
                         f'spiType="clothoid"><Start>{ne(p0)}</Start><PI>{ne(pi)}</PI><End>{ne(p1)}</End></Spiral>')
        joints += [s0, s0 + e.length_m]
    joints = sorted(set(joints))
    cant = design.evaluate(joints).cant_m if joints else []
    cant_xml = "".join(f'<CantStation station="{num(sta0 + s)}" appliedCant="{num(1000 * abs(c))}" '
                       f'curvature="{"cw" if c > 0 else "ccw"}"/>' for s, c in zip(joints, cant))
    pvis = "".join(f'<ParaCurve length="{num(p.curve_length_m)}">{num(sta0 + p.chainage_m)} {num(p.u_m)}</ParaCurve>'
                   if p.curve_length_m else f"<PVI>{num(sta0 + p.chainage_m)} {num(p.u_m)}</PVI>"
                   for p in design.config.vertical.pvis)
    body = (f'<Alignment name="R" staStart="{num(sta0)}"><CoordGeom>{"".join(parts)}</CoordGeom>'
            f"<Profile><ProfAlign>{pvis}</ProfAlign></Profile>"
            + (f'<Cant gauge="1.435">{cant_xml}</Cant>' if cant_xml else "") + "</Alignment>")
    return _write(path, body)


@hst.composite
def _designs(draw):
    """Random tangent - clothoid - arc - clothoid runs (curving either way, with cant), random pose
    and vertical profile (grades within 5 %)."""
    L = hst.floats(5.0, 300.0)
    elements = [{"type": "tangent", "length_m": draw(L)}]
    for _ in range(draw(hst.integers(1, 3))):
        r = draw(hst.floats(150.0, 5000.0)) * draw(hst.sampled_from([-1.0, 1.0]))
        elements += [{"type": "clothoid", "length_m": draw(hst.floats(10.0, 150.0))},
                     {"type": "arc", "length_m": draw(L), "radius_m": r, "cant_mm": draw(hst.floats(0.0, 160.0))},
                     {"type": "clothoid", "length_m": draw(hst.floats(10.0, 150.0))},
                     {"type": "tangent", "length_m": draw(L)}]
    total = sum(e["length_m"] for e in elements)
    s_pvi = np.sort(draw(hst.lists(hst.floats(0.05, 0.95), min_size=0, max_size=3, unique=True))) * total
    knots = np.concatenate([[0.0], s_pvi, [total]])
    grades = draw(hst.lists(hst.floats(-0.05, 0.05), min_size=len(knots) - 1, max_size=len(knots) - 1))
    u = draw(hst.floats(-50.0, 500.0)) + np.concatenate([[0.0], np.cumsum(np.diff(knots) * np.array(grades))])
    pvis = [{"chainage_m": float(s), "u_m": float(z)} for s, z in zip(knots, u)]
    for k in range(1, len(pvis) - 1):
        room = min(knots[k] - knots[k - 1], knots[k + 1] - knots[k])
        if room > 1.0:
            pvis[k]["curve_length_m"] = draw(hst.sampled_from([0.0, 1.0, 1.8 * room]) | hst.floats(1.0, 1.8 * room))
    return {"horizontal": {"start_e_m": draw(hst.floats(-20_000.0, 20_000.0)),
                           "start_n_m": draw(hst.floats(-20_000.0, 20_000.0)),
                           "heading_deg": draw(hst.floats(-180.0, 180.0)), "elements": elements},
            "vertical": {"pvis": pvis}}


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cfg=_designs(), sta0=hst.floats(0.0, 1e5))
def test_random_designs_round_trip_through_landxml(tmp_path, cfg, sta0):
    original = DesignAlignment.from_dict(cfg)
    back = load_design(_as_landxml(original, tmp_path / "round.xml", sta0))
    s = np.linspace(0.0, original.length_m, 2001)
    a, b = original.evaluate(s), back.evaluate(s)
    assert back.length_m == pytest.approx(original.length_m, rel=1e-12)
    assert np.abs(a.pos_n - b.pos_n).max() < 5e-10  # measured over 200 examples: 1.1e-10 m (at up to 22 km)
    assert np.abs(np.angle(np.exp(1j * (a.heading_rad - b.heading_rad)))).max() < 1e-13  # the same modulo 2 pi
    for name, tol in (("cant_m", 5e-13), ("curvature_h_1pm", 1e-15)):
        assert np.abs(getattr(a, name) - getattr(b, name)).max() < tol, name
    # stations (staStart + chainage, up to 1e5 m) carry the chainages to ~1e-11 m: grades to ~1e-12, and
    # the kinks of the grade (PVIs without a curve) and jumps of vertical curvature (curve ends) move as much
    ends = [p.chainage_m + h * p.curve_length_m / 2 for p in original.config.vertical.pvis for h in (-1, 1)]
    away = np.min(np.abs(s[:, None] - np.array(ends)[None, :]), axis=1) > 1e-6
    assert np.abs(a.slope_rad - b.slope_rad)[away].max() < 1e-11
    assert np.abs(a.curvature_v_1pm - b.curvature_v_1pm)[away].max() < 1e-11


@pytest.mark.parametrize("name", available_scenarios())
def test_every_scenario_design_round_trips_through_landxml(tmp_path, name):
    original = DesignAlignment.from_dict(load_scenario(name).alignment)
    back = load_design(_as_landxml(original, tmp_path / f"{name}.xml", 0.0))
    s = np.linspace(0.0, original.length_m, 4001)
    a, b = original.evaluate(s), back.evaluate(s)
    assert np.abs(a.pos_n - b.pos_n).max() < 5e-10
    assert np.abs(a.cant_m - b.cant_m).max() < 5e-13
    assert np.abs(a.R_nt - b.R_nt).max() < 1e-12


@pytest.mark.slow
def test_a_run_with_the_landxml_design_gives_the_yaml_designs_geometry(tmp_path):
    """``trackfusion run`` on an ideal simulated survey, once with the scenario's design in YAML,
    once as LandXML (inputs.design: design.xml): the same geometry.csv."""
    short = ["motion.passes=1", "motion.start_m=40", "motion.segments=[{hold_s: 30}, "
             "{move_to_m: 100, speed_mps: 3, accel_mps2: 0.4}, {hold_s: 10}]"]
    simulate_to_dir("open-track-gnss", tmp_path, seed=3, ideal=True, overrides=short)
    alignment = json.loads((tmp_path / "truth.json").read_text())["config"]["alignment"]
    (tmp_path / "design.yaml").write_text(yaml.safe_dump({"alignment": alignment}))
    _as_landxml(DesignAlignment.from_dict(alignment), tmp_path / "design.xml", 2500.0)
    tables = []
    for design in ("design.yaml", "design.xml"):
        p = yaml.safe_load((tmp_path / "pipeline.yaml").read_text())
        p["inputs"]["design"] = design
        (tmp_path / "p.yaml").write_text(yaml.safe_dump(p))
        out = tmp_path / f"out_{design.split('.')[1]}"
        assert main(["run", str(tmp_path / "p.yaml"), "--out", str(out)]) == 0
        assert json.loads((out / "metrics.json").read_text())["geometry"]["chainage"] == "design (projection)"
        tables.append(read_csv_table(out / "geometry.csv"))
    a, b = tables
    assert list(a) == list(b) and a["chainage_m"].size > 200
    worst = {col: float(np.nanmax(np.abs(a[col] - b[col]))) for col in a}  # measured: all 0 as written
    for col in a:
        assert np.array_equal(np.isnan(a[col]), np.isnan(b[col])), col
        assert worst[col] < 1e-6 or np.isnan(a[col]).all(), col  # (all NaN: not measured, no gauge sensor)


_TOKENS = [m.span() for m in re.finditer(r'"[^"]*"|>[^<]+<', CURVE_XML.read_text())]
_ODD = ['""', '"-1"', '"0"', '"INF"', '"-INF"', '"NaN"', '"1e308"', '"1e-300"', '"abc"', '"cw"', '"ccw"',
        '"clothoid"', ">1 2 3 4<", "><", ">nan nan<", ">1e308 1e308<", ">0 0<", ">1 1e308<"]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(changes=hst.lists(hst.tuples(hst.sampled_from(_TOKENS), hst.sampled_from(_ODD)), min_size=1, max_size=3,
                         unique_by=lambda c: c[0]))
def test_mangled_files_give_a_model_or_one_line(tmp_path, changes):
    """Any attribute value or text of the hand-written file replaced by an odd one: either a
    design or a one-line ConfigError, never another exception."""
    text = CURVE_XML.read_text()
    for (a, b), odd in sorted(changes, reverse=True):
        text = text[:a] + (odd if odd[0] == text[a] else text[a] + odd[1:-1] + text[b - 1]) + text[b:]
    path = _write_text(tmp_path / "mangled.xml", text)
    try:
        design = load_design(path)
    except ConfigError as exc:
        assert "\n" not in str(exc) and str(exc).startswith(str(path))
    else:
        assert np.all(np.isfinite(design.evaluate(np.linspace(0, design.length_m, 50)).pos_n))
