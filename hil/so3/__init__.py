"""Rotation-group utilities (SO(3)) shared by the estimator, the plant and the controller. Pure math.

Conventions: rotation matrices ``R`` of shape (3, 3) map body-frame vectors to the inertial frame
(``v_inertial = R @ v_body``); angular velocities are body-frame, rad/s, shape (3,). Functions accept
stacked inputs where noted (leading batch dimensions ``...``). :mod:`.arrays` works on numpy arrays,
:mod:`.floats` on Python floats, one step at a time (``*_f``).
"""

from .arrays import (
    Array,
    angle_between,
    euler_zyx,
    exp,
    hat,
    is_rotation,
    log,
    matrix_to_quat,
    orthonormality_error,
    principal_angle,
    project,
    quat_to_matrix,
    vee,
)
from .floats import (
    Mat9,
    Vec3,
    apply_f,
    apply_transpose_f,
    exp_f,
    log_f,
    mat9,
    matmul_f,
    reorthonormalize_f,
    rodrigues_coefficients,
    rotate_f,
    solve3_f,
    vec3,
)

__all__ = [
    "Array",
    "Mat9",
    "Vec3",
    "angle_between",
    "euler_zyx",
    "apply_f",
    "apply_transpose_f",
    "exp",
    "exp_f",
    "hat",
    "is_rotation",
    "log",
    "log_f",
    "mat9",
    "matmul_f",
    "matrix_to_quat",
    "orthonormality_error",
    "principal_angle",
    "project",
    "quat_to_matrix",
    "reorthonormalize_f",
    "rodrigues_coefficients",
    "rotate_f",
    "solve3_f",
    "vec3",
    "vee",
]
