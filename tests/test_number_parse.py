"""The reader's vectorised JSON number parse (sensors/number_parse.py) gives float()'s bits."""

from __future__ import annotations

import itertools
import json
import math
from decimal import Decimal, localcontext

import numpy as np
import pytest

from trackfusion.sensors.number_parse import parse_numbers


def _same_as_float(tokens: list[bytes]) -> None:
    values = parse_numbers(b" ".join(tokens))
    expected = np.array([float(t) for t in tokens])
    assert values is not None and values.shape == expected.shape
    differ = np.flatnonzero(values.view(np.int64) != expected.view(np.int64))
    assert differ.size == 0, [(tokens[i], values[i], expected[i]) for i in differ[:5]]


def test_repr_of_random_bit_patterns_over_the_whole_range():
    """Every finite float64 (random sign, exponent, mantissa: normal, subnormal) parses back exactly."""
    bits = np.random.default_rng(1).integers(0, 2**64, size=400_000, dtype=np.uint64)
    values = bits.view(np.float64)
    _same_as_float([repr(v).encode() for v in values[np.isfinite(values)].tolist()])


def test_sensor_like_values_and_short_decimals():
    rng = np.random.default_rng(2)
    values = rng.standard_normal(200_000) * 10.0 ** rng.integers(-12, 12, 200_000)
    quantised = np.round(rng.standard_normal(50_000) * 100, 6)  # a logger's fixed decimals
    _same_as_float([repr(v).encode() for v in values.tolist()] + [str(v).encode() for v in quantised.tolist()])


def test_random_decimal_texts_with_any_digits_and_exponents():
    """Up to 25 digits, any decimal point, exponents with and without sign (also beyond the range)."""
    rng = np.random.default_rng(3)
    tokens = []
    for _ in range(60_000):
        digits = "".join(map(str, rng.integers(0, 10, rng.integers(1, 26)))).lstrip("0") or "0"
        text = "-" * int(rng.integers(2)) + digits
        if len(digits) > 1 and rng.integers(2):
            k = int(rng.integers(1, len(digits)))
            text = text[:len(text) - k] + "." + text[len(text) - k:]
        if rng.integers(2):
            text += str(rng.choice(["e", "E"])) + str(rng.choice(["", "-", "+"])) + str(rng.integers(0, 400))
        tokens.append(text.encode())
    _same_as_float(tokens)


def test_exact_halfway_points_between_doubles_round_to_even():
    """Exact decimal midpoints between neighbouring doubles (the ties) and their neighbours."""
    rng = np.random.default_rng(4)
    tokens = []
    with localcontext() as ctx:
        ctx.prec = 800
        for x in (rng.standard_normal(3000) * 10.0 ** rng.integers(-300, 300, 3000)).tolist():
            mid = (Decimal(x) + Decimal(math.nextafter(x, math.inf))) / 2
            tokens += [format(mid, "e").encode(), format(mid.next_plus(), "e").encode(),
                       format(mid.next_minus(), "e").encode(), format(mid, ".17e").encode()]
    _same_as_float(tokens)


EDGES = [b"0", b"-0", b"0.0", b"-0.0", b"0e5", b"-0E-5", b"0.000", b"1", b"-1", b"9007199254740993",
         b"9007199254740992.5", b"1e23", b"8.98846567431158e307", b"2.2250738585072011e-308",
         b"2.2250738585072014e-308", b"4.9e-324", b"5e-324", b"2.4703282292062327e-324", b"2.4703282292062328e-324",
         b"1.7976931348623157e308", b"1.7976931348623158e308", b"1.7976931348623159e308", b"1e400", b"-1e400",
         b"1e-400", b"123456789012345678901234567890", b"0.000000000000000000000000000001234", b"1e00005",
         b"1E+2", b"1e-0", b"0.1", b"0.30000000000000004", b"1.00000000000000011102230246251565404236316680908203125",
         b"9.80665", b"-3.5e-05", b"18446744073709551615", b"9999999999999999999", b"10000000000000000000",
         b"99999999999999999999e-20", b"1e-342", b"1e-343", b"1e308", b"1e309", b"7.2057594037927933e16"]


def test_edge_values():
    """Signed zeros, subnormals, the largest and smallest normals, overflow to inf, underflow to 0,
    more than 19 digits, long exponents, ties."""
    _same_as_float(EDGES)
    values = parse_numbers(b"-0.0 0.0 -0 0e-7")
    assert np.signbit(values).tolist() == [True, False, True, False]


@pytest.mark.parametrize("token", ["01.5", "+1.5", ".5", "1.", "1e", "-", "1.2.3", "1e2.5", "1e+-2", "-01", "--1",
                                   "1-", "1e5e3", "e5", "1.e5", "00", "-.5", "1e+", "+", "."])
def test_non_json_numbers_are_refused(token):
    assert parse_numbers(b"1.5 " + token.encode() + b" 2") is None
    assert parse_numbers(token.encode()) is None


def test_grammar_matches_json_for_every_short_text():
    """Every text of 1 to 3 number characters: refused exactly when json refuses it."""
    def is_number(tok: str) -> bool:
        try:
            return type(json.loads(tok)) in (int, float)
        except ValueError:
            return False

    for size in (1, 2, 3):
        for chars in itertools.product("0123456789.eE+-", repeat=size):
            token = "".join(chars)
            values = parse_numbers(b"7 " + token.encode())
            assert (values is not None) == is_number(token), token
            if values is not None:
                assert values[1].tobytes() == np.float64(float(token)).tobytes(), token


def test_separators_and_empty_text():
    assert parse_numbers(b"").size == 0 and parse_numbers(b"   ").size == 0
    assert parse_numbers(b"  1.5   -2e3 7").tolist() == [1.5, -2000.0, 7.0]
