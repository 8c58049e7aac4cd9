"""MuJoCo's C functions as kernels call them (servo_app.motion.mujoco_c) give the Python binding's
numbers to the bit, on every arm model (random joints, every site, geom pair and rotation)."""

from __future__ import annotations

import re

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from servo_app.motion.mujoco_c import (
    address,
    check_version,
    doubles,
    mj_comPos,
    mj_geomDistance,
    mj_jacSite,
    mj_kinematics,
    mj_makeConstraint,
    mju_mat2Quat,
    mju_rotVecQuat,
)
from servo_app.robots.model import load_model
from servo_app.robots.profile import available_profiles, load_profile

MODELS = {name: load_model(load_profile(name)) for name in available_profiles()}


# The kernels under test (compiled once here, on first call: tests, not the cycle).
@njit
def _kinematics(m: int, d: int, constraints: bool) -> None:
    mj_kinematics(address(m), address(d))
    mj_comPos(address(m), address(d))
    if constraints:
        mj_makeConstraint(address(m), address(d))


@njit
def _jac_site(m: int, d: int, jac: np.ndarray, site: int) -> None:
    mj_jacSite(address(m), address(d), doubles(jac[:3]), doubles(jac[3:]), np.int32(site))


@njit
def _mat2quat(quat: np.ndarray, mat: np.ndarray) -> None:
    mju_mat2Quat(doubles(quat), doubles(mat))


@njit
def _rot_vec_quat(res: np.ndarray, vec: np.ndarray, quat: np.ndarray) -> None:
    mju_rotVecQuat(doubles(res), doubles(vec), doubles(quat))


@njit
def _geom_distance(m: int, d: int, g1: int, g2: int, distmax: float, fromto: np.ndarray) -> float:
    return mj_geomDistance(address(m), address(d), np.int32(g1), np.int32(g2), distmax, doubles(fromto))


@pytest.mark.parametrize("name", sorted(MODELS))
@settings(max_examples=15, deadline=None)
@given(u=st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6), distmax=st.sampled_from([0.05, 0.2, 10.0]))
def test_each_function_gives_the_bindings_bits(name: str, u: list[float], distmax: float) -> None:
    model = MODELS[name]
    lo, hi = model.jnt_range[:, 0], model.jnt_range[:, 1]
    q = lo + np.array(u) * (hi - lo)
    ours, theirs = mujoco.MjData(model), mujoco.MjData(model)
    ours.qpos[:] = q
    theirs.qpos[:] = q
    _kinematics(model._address, ours._address, model.neq > 0)
    mujoco.mj_kinematics(model, theirs)
    mujoco.mj_comPos(model, theirs)
    if model.neq > 0:
        mujoco.mj_makeConstraint(model, theirs)
    for field in ("xpos", "xquat", "xmat", "site_xpos", "site_xmat", "geom_xpos", "geom_xmat", "cdof",
                  "subtree_com"):
        assert np.array_equal(getattr(ours, field), getattr(theirs, field)), field
    for site in range(model.nsite):
        a, b = np.zeros((6, model.nv)), np.zeros((6, model.nv))
        _jac_site(model._address, ours._address, a, site)
        mujoco.mj_jacSite(model, theirs, b[:3], b[3:], site)
        assert np.array_equal(a, b)
        qa, qb = np.zeros(4), np.zeros(4)
        _mat2quat(qa, np.ascontiguousarray(ours.site_xmat[site]))
        mujoco.mju_mat2Quat(qb, theirs.site_xmat[site])
        assert np.array_equal(qa, qb)
        vec = np.array(u[:3]) - 0.5
        ra, rb = np.zeros(3), np.zeros(3)
        _rot_vec_quat(ra, vec, qa)
        mujoco.mju_rotVecQuat(rb, vec, qb)
        assert np.array_equal(ra, rb)
    for g1 in range(model.ngeom):
        for g2 in range(g1 + 1, model.ngeom):
            fa, fb = np.zeros(6), np.zeros(6)
            da = _geom_distance(model._address, ours._address, g1, g2, distmax, fa)
            db = mujoco.mj_geomDistance(model, theirs, g1, g2, distmax, fb)
            assert da == db and np.array_equal(fa, fb), (g1, g2)


@pytest.mark.parametrize("version", ["4.0.0", "2.3.7", "10.1", "dev"])
def test_an_unchecked_mujoco_major_version_is_refused_with_the_fix(version: str) -> None:
    with pytest.raises(ImportError, match=rf"mujoco {re.escape(version)} is installed.*pip install 'mujoco>=3.1,<4'"):
        check_version(version)


def test_the_installed_mujoco_is_a_checked_one() -> None:
    check_version(mujoco.__version__)  # (importing the module already did; this names the version on failure)
    check_version("3.1.0")
    check_version("3.17.0")
