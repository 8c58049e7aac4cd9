"""MuJoCo model of a profile: load its MJCF, apply the profile's joint ranges and the cell's tool.

The MJCF world frame *is* the FANUC world frame (the base body sits at z = -d1), so site poses read
from MuJoCo compare directly with :meth:`ArmKinematics.fk`.

Every model returned by :func:`load_model` has two sites on the last link:

- ``flange``: the flange frame (z out of the flange), fixed by the MJCF file;
- ``tcp``: the tool centre point, ``flange @ xyzwpr_to_matrix(tool_xyzwpr)``; identical to the
  flange when no tool is given. A cell configures its tool as FANUC UTOOL data (X Y Z mm, W P R deg)
  and passes it here; an MJCF that already has a ``tcp`` site gets it moved, not duplicated.
"""

from __future__ import annotations

import mujoco
import numpy as np

from servo_app.robots.conventions import ArrayLike, xyzwpr_to_matrix
from servo_app.robots.profile import ProfileError, RobotProfile

JOINT_NAMES = tuple(f"joint{i}" for i in range(1, 7))
FLANGE_SITE = "flange"
TCP_SITE = "tcp"


def load_spec(profile: RobotProfile, tool_xyzwpr: ArrayLike | None = None) -> mujoco.MjSpec:
    """The editable MjSpec (add tool geoms, obstacles, ... before ``compile()``)."""
    try:
        spec = mujoco.MjSpec.from_file(str(profile.mjcf))
    except ValueError as exc:
        raise ProfileError(f"{profile.mjcf}: MJCF does not load: {exc}") from exc
    for i, name in enumerate(JOINT_NAMES):
        joint = spec.joint(name)
        if joint is None:
            raise ProfileError(f"{profile.mjcf}: missing joint '{name}' (profile {profile.source})")
        # The profile is the single source of truth for ranges; the MJCF values are informative.
        joint.range = [profile.joint_min_rad[i], profile.joint_max_rad[i]]
        joint.limited = mujoco.mjtLimited.mjLIMITED_TRUE
    flange = spec.site(FLANGE_SITE)
    if flange is None:
        raise ProfileError(f"{profile.mjcf}: missing site '{FLANGE_SITE}' (profile {profile.source})")
    try:
        set_tool(spec, tool_xyzwpr)  # compiles once to resolve the flange site's frame
    except ValueError as exc:
        raise ProfileError(f"{profile.mjcf}: MJCF does not compile: {exc}") from exc
    return spec


def set_tool(spec: mujoco.MjSpec, tool_xyzwpr: ArrayLike | None) -> mujoco.MjsSite:
    """Add or move the ``tcp`` site to ``flange @ tool`` (tool in FANUC units, relative to the flange)."""
    flange = spec.site(FLANGE_SITE)
    body = flange.parent
    flange_t = _compiled_site_in_body(spec, FLANGE_SITE)
    tool = np.eye(4) if tool_xyzwpr is None else xyzwpr_to_matrix(tool_xyzwpr)
    t = flange_t @ tool  # in the flange's body frame
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(t[:3, :3]).reshape(9))
    site = spec.site(TCP_SITE)
    if site is not None and site.parent.name != body.name:
        spec.delete(site)
        site = None
    if site is None:
        site = body.add_site(name=TCP_SITE)
        site.size = flange.size
        site.rgba = [0.0, 1.0, 0.0, 1.0]
    site.pos = t[:3, 3]
    site.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT
    site.quat = quat
    return site


def set_model_tool(model: mujoco.MjModel, tool_xyzwpr: ArrayLike | None) -> None:
    """Move a compiled model's ``tcp`` site to ``flange @ tool`` in place: what :func:`set_tool`
    and a recompile give (both sites hang on the same body), without rebuilding the model, so a
    running IK keeps its model, data and every array derived from them."""
    flange, tcp = model.site(FLANGE_SITE), model.site(TCP_SITE)
    if int(model.site_bodyid[tcp.id]) != int(model.site_bodyid[flange.id]):
        raise ValueError(f"the {TCP_SITE!r} site is not on the flange's body")
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, flange.quat)
    flange_t = np.eye(4)
    flange_t[:3, :3] = mat.reshape(3, 3)
    flange_t[:3, 3] = flange.pos
    t = flange_t @ (np.eye(4) if tool_xyzwpr is None else xyzwpr_to_matrix(tool_xyzwpr))
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(t[:3, :3]).reshape(9))
    model.site_pos[tcp.id] = t[:3, 3]
    model.site_quat[tcp.id] = quat
    # The compiler marks a site whose frame coincides with its body's (site_sameframe) and kinematics
    # then skips site_pos/site_quat: a model compiled with a tool turned 180 deg about W kept that
    # flag, and the moved site's pose came out turned 180 deg (tests/test_tools.py). Not the same now.
    model.site_sameframe[tcp.id] = mujoco.mjtSameFrame.mjSAMEFRAME_NONE


def load_model(profile: RobotProfile, tool_xyzwpr: ArrayLike | None = None, *, verify: bool = True
               ) -> mujoco.MjModel:
    """Compiled MjModel of the profile's MJCF with the profile's joint ranges and a ``tcp`` site.

    ``verify`` checks that the MJCF's kinematics match the profile's dimensions (see
    :func:`check_against_profile`), so a hand-written model cannot silently disagree with FK/IK.
    """
    model = load_spec(profile, tool_xyzwpr).compile()
    if verify:
        check_against_profile(profile, model)
    return model


def check_against_profile(profile: RobotProfile, model: mujoco.MjModel, tol_m: float = 1e-6) -> None:
    """Raise ProfileError when the model's flange pose differs from ArmKinematics.fk at test poses."""
    from servo_app.robots.kinematics import ArmKinematics

    kin = ArmKinematics(profile)
    data = mujoco.MjData(model)
    probes = np.array([[0.0] * 6, [0.3, -0.4, 0.5, -0.6, 0.7, -0.8], [-1.1, 0.9, -0.7, 1.3, -1.2, 2.0]])
    for q in probes:
        err = float(np.abs(mujoco_fk(model, data, q) - kin.fk(q)).max())
        if err > tol_m:
            raise ProfileError(
                f"{profile.mjcf}: flange pose differs from the dimensions of {profile.source} by {err:.3g} "
                f"at q = {q.tolist()} rad (world frame, axes, offsets or flange site orientation)")


def site_pose(model: mujoco.MjModel, data: mujoco.MjData, name: str) -> np.ndarray:
    """4x4 world pose of a site after kinematics have been computed on ``data``."""
    sid = model.site(name).id
    t = np.eye(4)
    t[:3, :3] = data.site_xmat[sid].reshape(3, 3)
    t[:3, 3] = data.site_xpos[sid]
    return t


def mujoco_fk(model: mujoco.MjModel, data: mujoco.MjData, q: ArrayLike, site: str = FLANGE_SITE
              ) -> np.ndarray:
    """Set the six arm joints (model convention, rad), run mj_kinematics, return the site's 4x4 pose."""
    for i, name in enumerate(JOINT_NAMES):
        data.qpos[model.joint(name).qposadr[0]] = q[i]
    mujoco.mj_kinematics(model, data)
    return site_pose(model, data, site)


def _compiled_site_in_body(spec: mujoco.MjSpec, name: str) -> np.ndarray:
    """4x4 pose of a site relative to its body; compiling resolves euler/axisangle/xyaxes forms."""
    model = spec.compile()
    site = model.site(name)
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, site.quat)
    t = np.eye(4)
    t[:3, :3] = mat.reshape(3, 3)
    t[:3, 3] = site.pos
    return t
