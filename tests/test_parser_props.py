"""Property tests of the parser: exact numbers, random valid programs, random bytes."""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gcodeplan.errors import GcodeError
from gcodeplan.gcode import read_moves
from gcodeplan.gcode.scan import parse_decimal
from gcodeplan.machine import Machine
from conftest import same_rows

_TMP = Path(tempfile.mkdtemp(prefix="gcodeplan-props-"))

decimals = st.builds(
    lambda sign, whole, frac, dot: sign + whole + ("." + frac if dot else ""),
    st.sampled_from(["", "-", "+"]),
    st.text("0123456789", min_size=1, max_size=9),
    st.text("0123456789", min_size=0, max_size=9),
    st.booleans(),
) | st.builds(lambda sign, frac: sign + "." + frac, st.sampled_from(["", "-"]),
              st.text("0123456789", min_size=1, max_size=12))


@given(decimals)
@settings(max_examples=400, deadline=None)
def test_kernel_numbers_equal_python_float(text):
    buf = np.frombuffer((text + " ").encode(), dtype=np.uint8)
    ok, value, end = parse_decimal(buf, 0, buf.shape[0])
    # 18 digits at most here: the fast path is exact whenever the mantissa fits 2**53
    digits = sum(c.isdigit() for c in text)
    if digits <= 15:
        assert ok
    if ok:
        assert value == float(text) and end == len(text)
        assert np.signbit(value) == np.signbit(float(text))


def test_kernel_numbers_long_mantissa_falls_back():
    for text in ("1.00000000000000000001", "123456789012345678", "0." + "0" * 30 + "1"):
        buf = np.frombuffer((text + "\n").encode(), dtype=np.uint8)
        ok, _, _ = parse_decimal(buf, 0, buf.shape[0])
        assert not ok          # Python's float() decides these


_num = st.floats(min_value=-500, max_value=500, allow_nan=False).map(lambda v: f"{v:.{3}f}")
_line = st.one_of(
    st.builds(lambda c, ws: f"{c} " + " ".join(f"{k}{v}" for k, v in ws),
              st.sampled_from(["G0", "G1", "g1", "G01"]),
              st.lists(st.tuples(st.sampled_from("XYZE"), _num), max_size=4, unique_by=lambda t: t[0])),
    st.builds(lambda f: f"G1 F{f}", st.integers(1, 20000)),
    st.sampled_from(["G90", "G91", "M82", "M83", "G92 E0", "G92 E1.5", ";TYPE:Perimeter", ";TYPE:Infill",
                     ";LAYER_CHANGE", ";Z:0.2", "M204 S1000", "M204 P800 T900", "M204 P500", "G4 P10",
                     "M106 S255", "; comment", "", "M221 S95", "M220 S110", "G28", "M400", "G21", "T0",
                     "G2 X1 Y1 I0.5 J0.5", "G3 X0 Y0 R2", "G1 X1 Y2 ; trailing", "N5 G1 X3", "(paren) G1 X2"]),
)


@given(st.lists(_line, max_size=40), st.sampled_from(["marlin", "klipper", "linuxcnc"]))
@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_random_valid_programs_never_raise_and_both_paths_agree(lines, flavor):
    path = _TMP / "prog.gcode"
    path.write_text("\n".join(lines) + "\n")
    try:
        a, ra = read_moves(str(path), Machine(flavor=flavor))
    except GcodeError as err:
        # the only refusals allowed in these programs are geometric: an arc that cannot be drawn
        assert "arc" in str(err).lower() or "radius" in str(err).lower() or "G2" in str(err) or \
            "G3" in str(err), str(err)
        return
    b, rb = read_moves(str(path), Machine(flavor=flavor), force_python=True)
    assert same_rows(a, b)
    assert ra.summary.to_json() == rb.summary.to_json()
    assert np.all(np.isfinite(a["move_d"])) and np.all(a["move_d"] >= 0)


@given(st.binary(max_size=300))
@settings(max_examples=300, deadline=None)
def test_random_bytes_give_a_result_or_a_gcode_error(data):
    path = _TMP / "junk.gcode"
    path.write_bytes(data)
    for force in (False, True):
        try:
            read_moves(str(path), Machine(flavor="marlin"), force_python=force)
        except GcodeError as err:
            assert str(err).startswith(str(path))


@given(st.lists(st.text(alphabet="GMXYZEFIJKRPSTNgxyze0123456789.- ;()*%{}=_\t\r", max_size=30),
                max_size=20))
@settings(max_examples=300, deadline=None)
def test_random_gcode_like_text_gives_a_result_or_a_gcode_error(lines):
    path = _TMP / "junk2.gcode"
    path.write_text("\n".join(lines))
    results = []
    for force in (False, True):
        try:
            results.append(read_moves(str(path), Machine(flavor="linuxcnc"), force_python=force)[0])
        except GcodeError as err:
            assert str(err).startswith(str(path))
            results.append(str(err))
    if isinstance(results[0], np.ndarray) and isinstance(results[1], np.ndarray):
        assert same_rows(results[0], results[1])
    else:
        assert type(results[0]) is type(results[1])
