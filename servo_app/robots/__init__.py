"""Robot profiles, MJCF models, FK, analytic IK and the FANUC conventions (J2/J3, WPR, configuration).

The MuJoCo side lives in :mod:`servo_app.robots.model` and is not imported here, so the pure-numpy
kinematics stay cheap to import (the simulator's limit checker needs only those).
"""

from servo_app.robots.configuration import ArmConfiguration, configuration_of
from servo_app.robots.conventions import (
    fanuc_deg_to_model_rad,
    matrix_to_xyzwpr,
    model_rad_to_fanuc_deg,
    xyzwpr_to_matrix,
)
from servo_app.robots.ik import IkSolution
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import ProfileError, RobotProfile, available_profiles, load_profile

__all__ = [
    "ArmConfiguration",
    "ArmKinematics",
    "IkSolution",
    "ProfileError",
    "RobotProfile",
    "available_profiles",
    "configuration_of",
    "fanuc_deg_to_model_rad",
    "load_profile",
    "matrix_to_xyzwpr",
    "model_rad_to_fanuc_deg",
    "xyzwpr_to_matrix",
]
