"""Robot profiles: the five shipped models, validation messages, adding a model without code."""

import shutil
from pathlib import Path

import mujoco
import numpy as np
import pytest

from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.model import load_model, mujoco_fk
from servo_app.robots.profile import REPO_CONFIG_DIR, ProfileError, load_profile

PAYLOAD = {"lrmate200id": 7, "lrmate200id7l": 7, "m10ia": 10, "m20ia": 20, "r2000ic165f": 165}
DIMS = {
    "lrmate200id": (0.330, 0.050, 0.330, 0.035, 0.335, 0.080),
    "lrmate200id7l": (0.330, 0.050, 0.440, 0.035, 0.420, 0.080),
    "m10ia": (0.450, 0.150, 0.600, 0.200, 0.640, 0.100),
    "m20ia": (0.525, 0.150, 0.790, 0.250, 0.835, 0.100),
    "r2000ic165f": (0.670, 0.312, 1.075, 0.225, 1.280, 0.215),
}


@pytest.mark.parametrize("name", sorted(PAYLOAD))
def test_shipped_profiles(name):
    p = load_profile(name)
    assert p.name == name
    assert p.interval_ms == 8
    assert p.j23_factor == 1.0
    assert p.max_payload_kg == PAYLOAD[name]
    d = p.dims
    assert (d.d1, d.a1, d.a2, d.a3, d.d4, d.d6) == DIMS[name]
    assert p.acc_limit == pytest.approx([5 * v for v in p.vel_limit])
    assert p.jerk_limit == pytest.approx([40 * v for v in p.vel_limit])
    assert p.mjcf.is_file()


LRMATE = (REPO_CONFIG_DIR / "lrmate200id.toml").read_text()


def _write(tmp_path: Path, text: str, name: str = "bad.toml") -> Path:
    (tmp_path / "mjcf").mkdir(exist_ok=True)
    shutil.copy(REPO_CONFIG_DIR / "mjcf" / "lrmate200id.xml", tmp_path / "mjcf" / "lrmate200id.xml")
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize(("old", "new", "key", "value"), [
    ("d4 = 0.335", 'd4 = "far"', "dimensions.d4", "'far'"),
    ("interval_ms = 8 ", "interval_ms = 6 ", "interval_ms", "6"),
    ("max_payload_kg = 7.0", "max_payload_kg = -1", "max_payload_kg", "-1"),
    ("min_deg = [-170,", "min_deg = [171,", "joints.min_deg[0]", "171"),
    ("max_speed_deg_s = [450, 380", "max_speed_deg_s = [450, 0", "joints.max_speed_deg_s[1]", "0"),
    ("acc_limit_deg_s2 = [2250, 1900, 2600, 2750, 2725, 5000]", "acc_limit_deg_s2 = [1, 2]",
     "joints.acc_limit_deg_s2", "[1, 2]"),
    ('mjcf = "mjcf/lrmate200id.xml"', 'mjcf = "mjcf/missing.xml"', "mjcf", "'mjcf/missing.xml'"),
    ("j23_factor = 1.0", "j23_factor = true", "j23_factor", "True"),
])
def test_validation_errors_name_file_key_value(tmp_path, old, new, key, value):
    assert old in LRMATE
    path = _write(tmp_path, LRMATE.replace(old, new, 1))
    with pytest.raises(ProfileError) as err:
        load_profile(path)
    msg = str(err.value)
    assert str(path) in msg
    assert key in msg
    assert value in msg


def test_missing_key_and_bad_toml(tmp_path):
    path = _write(tmp_path, LRMATE.replace("d6 = 0.080\n", ""))
    with pytest.raises(ProfileError, match=r"bad\.toml: missing key 'dimensions\.d6'"):
        load_profile(path)
    path = _write(tmp_path, "name = [", "broken.toml")
    with pytest.raises(ProfileError, match=r"broken\.toml: not valid TOML"):
        load_profile(path)
    with pytest.raises(ProfileError, match="unknown"):
        load_profile("no_such_robot")


def test_mjcf_without_required_joint_is_reported(tmp_path):
    path = _write(tmp_path, LRMATE)
    xml = tmp_path / "mjcf" / "lrmate200id.xml"
    xml.write_text(xml.read_text().replace('name="joint5"', 'name="wrist_bend"'))
    with pytest.raises(ProfileError, match="missing joint 'joint5'"):
        load_model(load_profile(path))


def test_mjcf_disagreeing_with_profile_dimensions_is_reported(tmp_path):
    path = _write(tmp_path, LRMATE.replace("a2 = 0.330", "a2 = 0.340"))
    with pytest.raises(ProfileError, match="flange pose differs from the dimensions"):
        load_model(load_profile(path))


def test_new_model_from_files_only(tmp_path, monkeypatch):
    """docs/robots.md: a profile plus an MJCF file in a directory on $SERVO_APP_ROBOTS, no code."""
    text = LRMATE.replace('name = "lrmate200id"', 'name = "myarm"').replace("a2 = 0.330", "a2 = 0.400")
    (tmp_path / "mjcf").mkdir()
    xml = (REPO_CONFIG_DIR / "mjcf" / "lrmate200id.xml").read_text()
    xml = xml.replace('<body name="link3" pos="0 0 0.33">', '<body name="link3" pos="0 0 0.4">')
    (tmp_path / "mjcf" / "myarm.xml").write_text(xml)
    (tmp_path / "myarm.toml").write_text(text.replace("mjcf/lrmate200id.xml", "mjcf/myarm.xml"))
    monkeypatch.setenv("SERVO_APP_ROBOTS", str(tmp_path))
    profile = load_profile("myarm")
    kin = ArmKinematics(profile)
    model = load_model(profile)
    q = np.array([0.3, -0.2, 0.4, 1.0, -0.7, 2.0])
    assert mujoco_fk(model, mujoco.MjData(model), q) == pytest.approx(kin.fk(q), abs=1e-9)
    assert kin.fk(np.zeros(6))[2, 3] == pytest.approx(0.435)
