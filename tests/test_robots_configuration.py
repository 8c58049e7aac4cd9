"""FANUC configuration strings: flip / up / top and turn numbers."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servo_app.robots.configuration import (
    ArmConfiguration,
    ConfigurationRegion,
    boundary_distances,
    configuration_of,
    turn_number,
    wrap_pi,
)
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import load_profile

KIN = ArmKinematics(load_profile("lrmate200id"))


def cfg(*deg: float) -> ArmConfiguration:
    return configuration_of(np.radians(deg), KIN)


def test_string_form_and_parse():
    c = ArmConfiguration(flip=True, up=False, top=True, turn1=-1, turn4=0, turn6=1)
    assert str(c) == "F D T, -1, 0, 1"
    assert ArmConfiguration.parse(str(c)) == c
    assert ArmConfiguration.parse("nut") == ArmConfiguration(False, True, True)
    assert ArmConfiguration.parse("F U B, 0, 0, -1").turn6 == -1
    with pytest.raises(ValueError, match="not a configuration"):
        ArmConfiguration.parse("X U T")


def test_known_poses():
    assert str(cfg(0, 0, 0, 0, 0, 0)) == "N U T, 0, 0, 0"  # J5 = 0 reads No-flip
    assert str(cfg(0, 0, 0, 0, -90, 0)) == "N U T, 0, 0, 0"  # tool pointing down
    assert str(cfg(0, 0, 0, 180, 90, 180)) == "F U T, 0, 0, 0"  # same pose, wrist flipped
    assert not cfg(0, 0, 170, 0, -30, 0).up  # forearm folded back past the upper-arm line
    assert not cfg(0, -100, 0, 0, -30, 0).top  # wrist centre behind the J1 axis
    assert cfg(0, -100, 0, 0, -30, 0).up


def test_turn_numbers():
    assert [turn_number(math.radians(a)) for a in (180, -180, 181, -181, 540, 539.9, 0)] == [0, -1, 1, -1, 1, 1, 0]
    c = cfg(-181, 0, 0, 200, -30, -360)
    assert (c.turn1, c.turn4, c.turn6) == (-1, 1, -1)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-3 * math.pi, 3 * math.pi), min_size=6, max_size=6),
       st.integers(-1, 1), st.integers(-1, 1), st.integers(-1, 1))
def test_whole_turns_change_only_turn_numbers(q, k1, k4, k6):
    q = np.array(q)
    base = configuration_of(q, KIN)
    moved = q + 2 * math.pi * np.array([k1, 0, 0, k4, 0, k6])
    c = configuration_of(moved, KIN)
    assert c.same_branch(base)
    assert (c.turn1, c.turn4, c.turn6) == (base.turn1 + k1, base.turn4 + k4, base.turn6 + k6)
    assert -math.pi < wrap_pi(float(q[0])) <= math.pi


joint_vectors = st.lists(st.floats(-2 * math.pi, 2 * math.pi), min_size=6, max_size=6).map(np.array)


@settings(max_examples=500, deadline=None)
@given(joint_vectors, st.lists(st.floats(-0.6, 0.6), min_size=6, max_size=6).map(np.array),
       st.lists(st.floats(0.0, 0.1), min_size=6, max_size=6).map(np.array))
def test_region_is_same_configuration_with_margins(q0, step, margins):
    """The region's box and wrist-side test say exactly what the definitions say: the same
    configuration as where it was built, and every boundary distance at least its margin."""
    region = ConfigurationRegion.around(q0, KIN, margins)
    assert region.reference == configuration_of(q0, KIN)
    q = q0 + step
    expected = configuration_of(q, KIN) == region.reference and bool(np.all(boundary_distances(q, KIN) >= margins))
    if not expected:  # skip points within rounding of a margin: either answer is right there
        near = np.abs(boundary_distances(q, KIN) - margins) < 1e-9
        if np.any(near):
            return
    assert bool(region.contains(q)[0]) == expected
    assert region.contains(np.stack([q0, q, q])).tolist()[1:] == [expected, expected]


def test_region_within_joint_ranges():
    q = np.radians([0, 10, 0, 0, -70, 0])
    region = ConfigurationRegion.around(q, KIN, np.zeros(6)).within(np.radians([-170] * 6), np.radians([170] * 6))
    assert region.contains(q)[0]
    assert not region.contains(np.radians([171, 10, 0, 0, -70, 0]))[0]  # outside the range, same turn
    assert not region.contains(np.radians([0, 10, 0, 0, 10, 0]))[0]  # J5 changed sign: flip
