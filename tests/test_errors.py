"""servo_app.errors.json_safe: a refusal's details always encode as strict JSON, finite values unchanged."""

from __future__ import annotations

import json
import math
from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from servo_app.errors import ECHO_CHARS, InvalidRequest, echoed, json_safe, validation_errors

_leaves = (st.none() | st.booleans() | st.integers() | st.text() | st.floats(allow_nan=True, allow_infinity=True)
           | st.builds(ValueError, st.text()) | st.binary(max_size=8))
_details = st.recursive(
    _leaves,
    lambda inner: (st.lists(inner, max_size=4) | st.tuples(inner, inner)
                   | st.dictionaries(st.text(max_size=5) | st.integers(), inner, max_size=4)),
    max_leaves=20)


def _same_where_finite(before: Any, after: Any) -> None:
    """Every value JSON can hold is unchanged; NaN and infinities are their names; the rest their text."""
    if isinstance(before, float) and not math.isfinite(before):
        assert after == str(before) and after in ("nan", "inf", "-inf")
    elif before is None or isinstance(before, bool | int | float | str):
        assert after == before and type(after) is type(before)
    elif isinstance(before, dict):
        assert list(after) == [str(k) for k in before]
        for k, v in before.items():
            _same_where_finite(v, after[str(k)])
    elif isinstance(before, list | tuple):
        assert isinstance(after, list) and len(after) == len(before)
        for b, a in zip(before, after, strict=True):
            _same_where_finite(b, a)
    else:
        assert after == str(before)


@given(_details)
def test_json_safe_always_encodes_as_strict_json(value: Any) -> None:
    safe = json_safe(value)
    json.dumps(safe, allow_nan=False)  # raises on NaN, infinities and objects JSON has no type for
    _same_where_finite(value, safe)


def test_json_safe_keeps_a_validation_errors_fields_and_names_its_nan() -> None:
    error = {"type": "finite_number", "loc": ("body", "linear", 0), "msg": "Input should be a finite number",
             "input": math.nan, "ctx": {"error": InvalidRequest("linear[0] = nan: send a finite number")}}
    assert json_safe([error]) == [{"type": "finite_number", "loc": ["body", "linear", 0],
                                   "msg": "Input should be a finite number", "input": "nan",
                                   "ctx": {"error": "linear[0] = nan: send a finite number"}}]


@given(_details)
def test_an_echo_is_the_value_or_the_start_of_its_json_within_the_bound(value: Any) -> None:
    echo = echoed(value)
    text = json.dumps(json_safe(value))
    if len(text) <= ECHO_CHARS:
        assert echo == json_safe(value)
    else:  # a string of the bound's characters and the length
        assert echo == f"{text[:ECHO_CHARS]}... ({len(text)} characters in all)"
        assert isinstance(echo, str) and len(echo) <= ECHO_CHARS + 40
    json.dumps(echo, allow_nan=False)


def test_validation_errors_keep_every_field_and_cut_only_a_long_input() -> None:
    errors = [{"type": "extra_forbidden", "loc": ("body", "junk"), "msg": "Extra inputs are not permitted",
               "input": "x" * 1_900_000},
              {"type": "finite_number", "loc": ("body", "joints", 0, 0), "msg": "m" * 600, "input": math.inf}]
    out = validation_errors(errors)
    assert out[0]["input"].endswith("... (1900002 characters in all)") and len(out[0]["input"]) < 600
    assert out[0]["loc"] == ["body", "junk"] and out[0]["msg"] == "Extra inputs are not permitted"
    assert out[1] == {"type": "finite_number", "loc": ["body", "joints", 0, 0], "msg": "m" * 600, "input": "inf"}
