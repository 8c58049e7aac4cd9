"""Command types of the diff-IK: validation and liveness."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from servo_app.motion.commands import JointJog, JointTarget, PoseTarget, Twist


def test_valid_commands_normalise_to_float_tuples() -> None:
    tw = Twist(linear=np.array([1, 2, 3]), angular=[0, 0, 10], frame="tool", source="spacemouse", stamp=1.5)
    assert tw.linear == (1.0, 2.0, 3.0) and isinstance(tw.linear[0], float)
    assert tw.angular == (0.0, 0.0, 10.0) and not tw.is_zero
    assert Twist(source="a", stamp=0.0).is_zero
    pt = PoseTarget(xyzwpr=[400, 0, 300, 180, 0, 0], linear_speed=250, angular_speed=90, source="api", stamp=0)
    assert pt.xyzwpr == (400.0, 0.0, 300.0, 180.0, 0.0, 0.0)
    jj = JointJog(velocity=[1, 0, 0, 0, 0, -5], source="web", stamp=2)
    assert jj.velocity[5] == -5.0
    jt = JointTarget(position=[0, 0, 0, 0, -90, 0], speed_scale=1.0, source="api", stamp=0)
    assert jt.speed_scale == 1.0


def test_fields_are_keyword_only_and_source_stamp_required() -> None:
    with pytest.raises(TypeError):
        Twist((1.0, 0.0, 0.0))  # type: ignore[misc]
    with pytest.raises(TypeError):
        Twist(linear=(1.0, 0.0, 0.0))  # type: ignore[call-arg]


def test_is_live_window() -> None:
    tw = Twist(linear=(1, 0, 0), source="s", stamp=10.0)
    assert tw.is_live(10.0, 0.1)
    assert tw.is_live(10.1, 0.1)
    assert not tw.is_live(10.1001, 0.1)
    assert not tw.is_live(9.99, 0.1)  # from the future: never extends a command's life
    assert tw.age(10.05) == pytest.approx(0.05)


@pytest.mark.parametrize(
    ("make", "field", "value"),
    [
        (lambda: Twist(linear=(math.nan, 0, 0), source="s", stamp=0), "linear[0]", "nan"),
        (lambda: Twist(linear=(0, 0, 0), angular=(0, math.inf, 0), source="s", stamp=0), "angular[1]", "inf"),
        (lambda: Twist(linear=(0, 0), source="s", stamp=0), "linear", "2 values"),
        (lambda: Twist(linear=(5000, 0, 0), source="s", stamp=0), "linear[0]", "5000"),
        (lambda: Twist(angular=(0, 0, -2000), source="s", stamp=0), "angular[2]", "-2000"),
        (lambda: Twist(frame="world", source="s", stamp=0), "frame", "world"),  # type: ignore[arg-type]
        (lambda: Twist(source="s", stamp=math.nan), "stamp", "nan"),
        (lambda: Twist(source=3, stamp=0), "source", "3"),  # type: ignore[arg-type]
        (lambda: Twist(linear=(0, "x", 0), source="s", stamp=0), "linear[1]", "'x'"),
        (lambda: PoseTarget(xyzwpr=(0, 0, 0, 0, 0), source="s", stamp=0), "xyzwpr", "5 values"),
        (lambda: PoseTarget(xyzwpr=(0, 0, math.nan, 0, 0, 0), source="s", stamp=0), "xyzwpr[2]", "nan"),
        (lambda: PoseTarget(xyzwpr=(0, 0, 0, 0, 0, 720), source="s", stamp=0), "xyzwpr[5]", "720"),
        (lambda: PoseTarget(xyzwpr=(0,) * 6, linear_speed=0, source="s", stamp=0), "linear_speed", "0.0"),
        (lambda: PoseTarget(xyzwpr=(0,) * 6, angular_speed=-1, source="s", stamp=0), "angular_speed", "-1"),
        (lambda: PoseTarget(xyzwpr=(0,) * 6, linear_speed=9000, source="s", stamp=0), "linear_speed", "9000"),
        (lambda: JointJog(velocity=(0, 0, 0, 0, 0), source="s", stamp=0), "velocity", "5 values"),
        (lambda: JointJog(velocity=(0, 0, 0, 0, 0, math.nan), source="s", stamp=0), "velocity[5]", "nan"),
        (lambda: JointJog(velocity=(0, 1500, 0, 0, 0, 0), source="s", stamp=0), "velocity[1]", "1500"),
        (lambda: JointTarget(position=(0, 0, 0, 0, 0, -math.inf), source="s", stamp=0), "position[5]", "inf"),
        (lambda: JointTarget(position=(0,) * 7, source="s", stamp=0), "position", "7 values"),
        (lambda: JointTarget(position=(0,) * 6, speed_scale=0.0, source="s", stamp=0), "speed_scale", "0.0"),
        (lambda: JointTarget(position=(0,) * 6, speed_scale=1.5, source="s", stamp=0), "speed_scale", "1.5"),
        (lambda: JointTarget(position=(0,) * 6, speed_scale=math.nan, source="s", stamp=0), "speed_scale", "nan"),
    ],
)
def test_invalid_values_raise_naming_field_and_value(make, field: str, value: str) -> None:
    with pytest.raises(ValueError) as err:
        make()
    assert field in str(err.value)
    assert value in str(err.value)


@given(st.tuples(*[st.floats(allow_nan=True, allow_infinity=True, width=64)] * 3),
       st.sampled_from([tuple, list, np.array]))
def test_a_tuple_of_floats_is_checked_as_any_other_sequence(values: tuple[float, ...], kind: type) -> None:
    """``_floats`` takes a tuple of finite floats as it is (the requests' usual case); it must accept and
    refuse exactly what the general path does for the same numbers in a list or an array."""
    def outcome(value: object) -> tuple[float, ...] | str:
        try:
            return Twist(linear=value, source="s", stamp=0.0).linear  # type: ignore[arg-type]
        except ValueError as exc:
            return str(exc)  # the field named, e.g. "linear[1]", with its value and the bounds

    got, general = outcome(kind(values)), outcome(list(values))
    assert got == general
    if isinstance(got, tuple):
        assert all(type(v) is float for v in got)
        assert all(math.isfinite(v) and abs(v) <= 4000.0 for v in got)


@given(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**6, 10**6), st.booleans(),
                 st.just("1.0")))
def test_a_stamp_is_a_finite_number_whatever_its_type(stamp: object) -> None:
    """The stamp's usual case (a finite float, taken as it is) and every other: a finite float or int
    becomes that float, anything else is refused naming the stamp."""
    try:
        got: float | str = Twist(linear=(1.0, 0.0, 0.0), source="s", stamp=stamp).stamp  # type: ignore[arg-type]
    except ValueError as exc:
        got = str(exc)
    if isinstance(stamp, int | float) and not isinstance(stamp, bool) and math.isfinite(stamp):
        assert got == float(stamp) and type(got) is float
    else:
        assert isinstance(got, str) and got.startswith("stamp="), got
