"""Exact vectorised parsing of JSON numbers (the reader's fast path, docs/read_speed.md).

:func:`parse_numbers` turns a text of space-separated JSON numbers into float64 values that are
bit for bit those of Python's ``float()`` (correctly rounded, round half to even), with numpy
operations on the bytes instead of one ``float()`` per number (about 4 times less CPU).

Method, per number ``[-] digits [. digits] [e [+-] digits]``:

1. the significant digits as an integer ``M < 10**19`` and the decimal exponent ``q``, so that
   the value is ``M * 10**q`` (integer arithmetic on the digit bytes: exact);
2. ``M`` normalised to ``w`` in ``[2**63, 2**64)`` times a 64-bit truncation ``T`` of ``5**q``
   scaled into ``[2**63, 2**64)`` (table made with Python integers): the exact high 64 bits
   ``H`` of the 128-bit product ``w * T``. The true scaled value lies in
   ``[H, H + 1)`` (units of the lowest bit of H: the product's low half and the table's
   truncation add less than one such unit);
3. the 53-bit mantissa is H's top 53 bits, rounded to nearest from H's remaining 10 or 11
   bits. Where those bits are the halfway pattern or one below it, the unit of doubt could
   decide the rounding (or the number is an exact tie): such numbers (about 1 in 500-1000)
   are parsed by ``float()`` instead, and so are those outside the plain cases (more than 19
   significant digits, exponents beyond 4 digits, results outside the normal float64 range).

Everything that is not decided exactly by step 3 goes to ``float()``, so the result never
differs from it (tests/test_number_parse.py compares both on millions of values and the edge
cases).
"""

from __future__ import annotations

import re

import numpy as np

_Q_MIN, _Q_MAX = -342, 308  # decimal exponents with a table entry (beyond: float())


def _power_table() -> tuple[np.ndarray, np.ndarray]:
    """For q in [_Q_MIN, _Q_MAX]: T_q (uint64) = floor of 5**q * 2**(63 - e_q), in [2**63, 2**64),
    and e_q = floor(log2(5**q)) (int64)."""
    t, e = [], []
    for q in range(_Q_MIN, _Q_MAX + 1):
        p = 5 ** abs(q)
        if q >= 0:
            e_q = p.bit_length() - 1
            t_q = p << (63 - e_q) if e_q <= 63 else p >> (e_q - 63)
        else:  # 5**q = 1 / p, p not a power of 2: floor(log2(1 / p)) = -bit_length(p)
            e_q = -p.bit_length()
            t_q = (1 << (63 + p.bit_length())) // p
        assert 1 << 63 <= t_q < 1 << 64
        t.append(t_q)
        e.append(e_q)
    return np.array(t, dtype=np.uint64), np.array(e, dtype=np.int64)


_T, _E5 = _power_table()
_POW10 = np.array([10 ** k for k in range(19)], dtype=np.uint64)
_LOW32 = np.uint64(0xFFFFFFFF)
_32 = np.uint64(32)


def _high_product(w: np.ndarray, t: np.ndarray) -> np.ndarray:
    """High 64 bits (uint64) of the exact 128-bit products ``w * t`` (uint64 arrays)."""
    w0, w1 = w & _LOW32, w >> _32
    t0, t1 = t & _LOW32, t >> _32
    p01, p10 = w0 * t1, w1 * t0
    mid = ((w0 * t0) >> _32) + (p01 & _LOW32) + (p10 & _LOW32)
    return w1 * t1 + (p01 >> _32) + (p10 >> _32) + (mid >> _32)


def _bit_length(m: np.ndarray) -> np.ndarray:
    """Bit lengths (int64) of positive uint64 ``m``."""
    bits = np.frexp(m.astype(np.float64))[1].astype(np.int64)  # may be one too many (rounding up)
    bits -= (m >> (bits - 1).astype(np.uint64)) == 0
    return bits


def _scale(m: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``m * 10**q`` rounded to float64 for positive uint64 ``m`` and q in the table's range;
    returns (values, decided): values are exact where ``decided`` (module docstring, step 3)."""
    lz = 64 - _bit_length(m)
    w = m << lz.astype(np.uint64)
    h = _high_product(w, _T[q - _Q_MIN])
    shift = 10 + (h >> np.uint64(63)).astype(np.int64)  # h in [2**62, 2**64): keep 53 bits
    shift_u = shift.astype(np.uint64)
    rest = h & ((np.uint64(1) << shift_u) - np.uint64(1))
    half = np.uint64(1) << (shift_u - np.uint64(1))
    mantissa = (h >> shift_u) + (rest > half)
    exponent = shift + 1 + q + _E5[q - _Q_MIN] - lz  # value = mantissa * 2**exponent
    decided = (rest != half) & (rest != half - np.uint64(1)) & (exponent >= -1074) & (exponent <= 970)
    exponent = np.where(decided, exponent, 0)  # (no overflow warnings for the undecided)
    return np.ldexp(mantissa.astype(np.float64), exponent.astype(np.int32)), decided


def _digits_value(digit: np.ndarray, read: np.ndarray) -> np.ndarray:
    """Per column, the integer of its digits where ``read`` (uint64, exact below 2**64).

    digit: (width, n) uint8 digit values; read: (width, n) bool, the digits to read (others are
    skipped). Pairs of rows are merged into factors and values of the pair (``v * f + d``) in
    small integer types, then groups of 8 rows are combined into the result in uint64."""
    factor = read * np.uint8(9) + np.uint8(1)
    value = digit * read
    if len(factor) % 8:
        raise ValueError("digits_value needs a multiple of 8 rows")
    for wider in (np.uint16, np.uint32, np.uint64):  # rows (a, b) -> (f_a f_b, d_a f_b + d_b)
        f_b = factor[1::2].astype(wider)
        value = value[0::2] * f_b + value[1::2]
        factor = factor[0::2] * f_b
    total = np.zeros(factor.shape[1], np.uint64)
    for f, v in zip(factor, value):
        total *= f
        total += v
    return total


def _first_row(mask: np.ndarray, none: int = 0) -> np.ndarray:
    """Per column of the (width, n) bool ``mask`` (width < 256), the first row where it is True
    (int64), ``none`` where no row is: with ``none=0`` what ``mask.argmax(axis=0)`` gives, but
    reduced row by row along the n columns (several times faster than argmax across the short
    columns)."""
    width = mask.shape[0]
    countdown = np.arange(width, 0, -1, dtype=np.uint8)[:, None]  # width - row
    best = (mask * countdown).max(axis=0)
    return np.where(best > 0, width - best.astype(np.int64), none)


def _column_counts(mask: np.ndarray) -> np.ndarray:
    """Per column of the (width, n) bool ``mask`` (width < 256), its True rows (int64)."""
    return np.add.reduce(mask.view(np.uint8), axis=0, dtype=np.uint8).astype(np.int64)


#: numbers longer than this are parsed by float() (JSON numbers written by repr have at most 24)
MAX_WIDTH = 40


def _token_bounds(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (exclusive) offsets of the runs of non-space bytes of ``a`` (uint8)."""
    inside = a != 32
    begins = np.flatnonzero(inside[1:] > inside[:-1]) + 1
    stops = np.flatnonzero(inside[1:] < inside[:-1]) + 1
    if inside.size and inside[0]:
        begins = np.concatenate([[0], begins])
    if inside.size and inside[-1]:
        stops = np.concatenate([stops, [inside.size]])
    return begins, stops


#: the JSON number grammar (RFC 8259), for the numbers checked one by one
_JSON_NUMBER = re.compile(rb"-?(?:0|[1-9][0-9]*)(?:\.[0-9]+)?(?:[eE][+-]?[0-9]+)?")


def parse_numbers(numbers: bytes) -> np.ndarray | None:
    """float64 values (N,) of the N space-separated numbers in ``numbers`` (bytes of the
    characters ``0-9 . e E + -`` and spaces), identical to ``float()`` of each; None when any of
    them is not a JSON number (e.g. ``+1``, ``01``, ``.5``, ``1.``, ``1e``: float() or numpy would
    take some of these).

    The numbers are laid out as a (width, N) character matrix (a number per column, so that
    every operation runs along the N numbers), from which the digits and the positions of the
    sign, the decimal point and the exponent give each number's grammar check, integer mantissa
    and decimal exponent (module docstring)."""
    a = np.frombuffer(numbers, np.uint8)
    starts, ends = _token_bounds(a)
    n = starts.size
    if n == 0:
        return np.zeros(0)
    lengths = ends - starts
    width = -(-int(min(lengths.max(), MAX_WIDTH)) // 8) * 8  # rows beyond a number's end are masked
    padded = np.concatenate([a, np.full(width + 8, 32, np.uint8)])
    chars = np.lib.stride_tricks.sliding_window_view(padded, width)[starts].T.copy()  # (width, n)
    column = np.arange(n)
    row = np.arange(width)[:, None]
    e_at = _first_row((chars | np.uint8(0x20)) == ord("e"))  # (0 when none: checked next)
    has_e = ((chars[e_at, column] | np.uint8(0x20)) == ord("e")) & (e_at < lengths)
    mantissa_end = np.where(has_e, e_at, np.minimum(lengths, width))
    dot_at = _first_row(chars == ord("."))
    has_dot = (chars[dot_at, column] == ord(".")) & (dot_at < mantissa_end)
    fraction_digits = np.where(has_dot, mantissa_end - dot_at - 1, 0)
    negative = chars[0] == ord("-")
    integer_digits = np.where(has_dot, dot_at, mantissa_end) - negative
    first_digit = padded[starts + negative]
    digit = chars - np.uint8(48)
    mantissa_digit = (digit < 10) & (row < mantissa_end)
    mantissa_digits = _column_counts(mantissa_digit)
    valid = ((mantissa_digits == mantissa_end - negative - has_dot) & (integer_digits >= 1)
             & ((integer_digits == 1) | (first_digit != ord("0"))) & (~has_dot | (fraction_digits >= 1)))
    m = _digits_value(digit, mantissa_digit)
    too_long = lengths > width
    long_mantissa = np.flatnonzero(mantissa_digits > 19)
    if long_mantissa.size:  # more than 19 digits from the first nonzero one on?
        first_nonzero = _first_row(mantissa_digit & (digit > 0), none=width)[long_mantissa]
        # the mantissa's digits before its first nonzero one are zeros: its characters from the
        # sign on, but the decimal point
        zeros = (first_nonzero - negative[long_mantissa]
                 - (has_dot[long_mantissa] & (dot_at[long_mantissa] < first_nonzero)))
        significant = np.where(first_nonzero < width, mantissa_digits[long_mantissa] - zeros, 0)
        too_long[long_mantissa] |= significant > 19
    del chars, digit, mantissa_digit
    # exponent: e, an optional sign, 1 to 4 digits (more: float())
    sign = padded[starts + e_at + 1]
    signed = (sign == ord("-")) | (sign == ord("+"))
    e_negative = has_e & (sign == ord("-"))
    first = e_at + 1 + signed
    too_long |= has_e & (lengths - first > 4)
    valid &= ~has_e | (lengths > first)
    e = np.zeros(n, np.uint64)
    for k in range(4):
        at = first + k
        more = has_e & (at < lengths)
        e_digit = padded[starts + at] - np.uint8(48)
        valid &= ~more | (e_digit < 10)
        e = np.where(more, e * np.uint64(10) + e_digit, e)
    hard = too_long.copy()
    if not valid[~hard].all():
        return None
    q = np.where(e_negative, -e.astype(np.int64), e.astype(np.int64)) - fraction_digits
    nonzero = m != 0
    easy = nonzero & ~too_long & (q >= _Q_MIN) & (q <= _Q_MAX)
    values = np.zeros(n)
    at = np.flatnonzero(easy)
    scaled, decided = _scale(m[at], q[at])
    values[at] = scaled
    hard |= nonzero & ~easy
    hard[at[~decided]] = True
    for i in np.flatnonzero(hard).tolist():
        token = numbers[starts[i]:ends[i]]
        if not _JSON_NUMBER.fullmatch(token):
            return None
        values[i] = float(token)
    values[negative & ~hard] *= -1.0  # (zeros become -0.0); float() gave the hard ones their sign
    return values
