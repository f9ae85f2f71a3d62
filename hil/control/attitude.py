"""Geometric attitude control on SO(3) (Lee, Leok & McClamroch 2010; Sanyal's S_L form): the torque the
VSCMG array must exert on the body to track a reference attitude, or to slew to one and stop. Pure math.

Attitude error (no quaternions, so no sign ambiguity and no unwinding)::

    e_R = ½ vex(K R_dᵀ R − Rᵀ R_d K)          e_Ω = Ω − Rᵀ R_d Ω_d

``K = diag(k₁, k₂, k₃)`` weights the error potential ``½ tr(K (I − R_dᵀ R))`` (the Sanyal form's
``S_L(R)`` with ``L = R_d K``); distinct weights make the identity the only stable equilibrium of an almost
globally attractive set, equal weights give Lee's ``e_R``. Control law, with J the locked inertia and
``h`` the array's momentum relative to the locked body (so that ``J Ω̇ = τ_fb`` when the array delivers it)::

    τ_fb = −K_R e_R − K_Ω e_Ω − K_I ∫e_R + J (Rᵀ R_d Ω̇_d − Ω^× Rᵀ R_d Ω_d)
    L_r  = τ_fb + Ω × (J Ω + h)                  the torque the array must exert on the body

Gains come from a natural frequency ω_n and damping ζ at the spacecraft's inertia: ``K_R = ω_n² J``,
``K_Ω = 2 ζ ω_n J``, so that small errors obey ``δθ̈ + 2ζω_n δθ̇ + ω_n² δθ = 0`` about every axis.
The optional integral term (time constant ``integral_time_s``, clamped) removes steady offsets from
constant disturbances (gravity gradient, a residual gyro bias).

Rest-to-rest slews: :class:`EigenaxisSlew` is a smooth (minimum-jerk) rotation about the fixed axis from
``R0`` to ``R_f``, within a rate and an acceleration limit, which the controller tracks.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil import so3
from hil.control.steering import TORQUE_SCALED_ABOVE
from hil.so3.floats import Mat9, Vec3, apply_f, exp_f, mat9, matmul_f, vec3
from protocol.errors import ConfigError

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Reference:
    """Desired attitude ``R`` (3, 3) body → inertial, body rate ``omega`` (3,) rad/s and its derivative
    ``omega_dot`` (3,) rad/s², both in the desired body frame."""

    R: Array
    omega: Array = field(default_factory=lambda: np.zeros(3))
    omega_dot: Array = field(default_factory=lambda: np.zeros(3))

    @functools.cached_property
    def floats(self) -> tuple[Mat9, Vec3, Vec3]:
        """``R`` as a row-major 9-tuple, ``omega`` and ``omega_dot`` as 3-tuples of floats: what the
        controller computes with (once per reference; :meth:`of_floats` gives them from the start)."""
        return mat9(self.R), vec3(self.omega), vec3(self.omega_dot)

    @classmethod
    def of_floats(cls, R: Mat9, omega: Vec3, omega_dot: Vec3) -> Reference:
        """The reference of these floats (row-major 9-tuple, 3-tuples), its :attr:`floats` kept as given:
        the slew makes one every control tick from floats, and the controller and the tick's record read
        them back as floats. (The arrays are the same numbers; changing one in place would not change
        :attr:`floats`.)"""
        ref = cls(np.array(R).reshape(3, 3), np.array(omega), np.array(omega_dot))
        ref.__dict__["floats"] = (R, omega, omega_dot)  # as cached_property stores it (frozen: no setattr)
        return ref


@dataclass(frozen=True)
class ControllerGains:
    """``natural_frequency`` ω_n (rad/s), ``damping`` ζ, ``weights`` (3,) the error-potential weights K,
    ``integral_time_s`` (None: no integral term) and ``integral_limit`` (rad s) clamping ∫e_R."""

    natural_frequency: float = 0.5
    damping: float = 0.9
    weights: tuple[float, float, float] = (1.0, 1.0, 1.0)
    integral_time_s: float | None = None
    integral_limit: float = 0.5

    def __post_init__(self) -> None:
        for name in ("natural_frequency", "damping", "integral_limit"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"must be positive, got {v!r}", f"ControllerGains.{name}")
        t_i = self.integral_time_s
        if t_i is not None and not (math.isfinite(t_i) and t_i > 0):  # no integral term is None, not inf
            raise ConfigError(
                f"must be positive and finite, or None, got {t_i!r}", "ControllerGains.integral_time_s"
            )
        if len(self.weights) != 3 or not all(math.isfinite(w) and w > 0 for w in self.weights):
            raise ConfigError(
                f"must be three positive weights, got {self.weights!r}", "ControllerGains.weights"
            )


@dataclass(frozen=True)
class ControlOutput:
    """``torque`` (3,) N m the array must exert on the body (L_r), ``feedback`` (3,) N m the τ_fb part,
    ``e_R`` (3,) and ``e_omega`` (3,) rad/s the errors, ``angle`` rad the principal angle of ``R_dᵀ R``."""

    torque: Array
    feedback: Array
    e_R: Array
    e_omega: Array
    angle: float


class AttitudeController:
    """The geometric controller above, for a spacecraft of locked inertia ``inertia`` (3, 3) kg m².

    ``update(R, omega, reference, dt, array_momentum)`` once per control period; ``dt`` (s) advances the
    integral term (0 leaves it)."""

    def __init__(self, inertia: ArrayLike, gains: ControllerGains | None = None) -> None:
        J = np.asarray(inertia, dtype=float)
        if J.shape != (3, 3) or not np.all(np.isfinite(J)) or np.linalg.eigvalsh(0.5 * (J + J.T))[0] <= 0:
            raise ConfigError("must be a positive definite 3x3 inertia", "AttitudeController.inertia")
        self.J = J
        self.gains = gains or ControllerGains()
        wn, zeta = self.gains.natural_frequency, self.gains.damping
        self.K_R = wn * wn * J
        self.K_Omega = 2.0 * zeta * wn * J
        _check_gain_matrices(self.K_R, self.K_Omega, self.gains)
        self.K = np.diag(self.gains.weights)
        self.integral = np.zeros(3)
        # the same matrices as 9-tuples, for update()'s float math
        self._J, self._K_R, self._K_Omega = mat9(J), mat9(self.K_R), mat9(self.K_Omega)
        k1, k2, k3 = (float(k) for k in self.gains.weights)
        self._k = (k1, k2, k3)

    def reset(self) -> None:
        self.integral = np.zeros(3)

    def errors(self, R: ArrayLike, omega: ArrayLike, ref: Reference) -> tuple[Array, Array, Array]:
        """``(e_R, e_Ω, Rᵀ R_d)`` for attitude ``R`` (3, 3) and body rate ``omega`` (3,)."""
        m = _transpose_matmul(mat9(R), mat9(ref.R))
        wx, wy, wz = vec3(omega)
        dx, dy, dz = apply_f(m, vec3(ref.omega))
        return np.array(self._attitude_error(m)), np.array((wx - dx, wy - dy, wz - dz)), np.reshape(m, (3, 3))

    def _attitude_error(self, m: Mat9) -> Vec3:
        """``e_R = ½ vee(K mᵀ − m K)`` for ``m = Rᵀ R_d`` (row-major 9-tuple), K diagonal."""
        k1, k2, k3 = self._k
        m0, m1, m2, m3, m4, m5, m6, m7, m8 = m
        a21, a12 = k3 * m5 - m7 * k2, k2 * m7 - m5 * k3  # A = K mᵀ − m K, element by element
        a02, a20 = k1 * m6 - m2 * k3, k3 * m2 - m6 * k1
        a10, a01 = k2 * m1 - m3 * k1, k1 * m3 - m1 * k2
        return 0.5 * (0.5 * (a21 - a12)), 0.5 * (0.5 * (a02 - a20)), 0.5 * (0.5 * (a10 - a01))

    def update(
        self,
        R: ArrayLike,
        omega: ArrayLike,
        ref: Reference,
        dt: float = 0.0,
        array_momentum: ArrayLike = (0.0, 0.0, 0.0),
    ) -> ControlOutput:
        R_d, w_ref, wd_ref = ref.floats
        torque, fb, e_R, e_w, m = self.update_floats(
            mat9(R), vec3(omega), R_d, w_ref, wd_ref, dt, vec3(array_momentum)
        )
        return ControlOutput(np.array(torque), np.array(fb), np.array(e_R), np.array(e_w), _angle(m))

    def update_floats(
        self, R: Mat9, omega: Vec3, R_d: Mat9, omega_d: Vec3, omega_dot_d: Vec3, dt: float, h: Vec3
    ) -> tuple[Vec3, Vec3, Vec3, Vec3, Mat9]:
        """:meth:`update` on Python floats (row-major 9-tuples, 3-tuples: ``hil.so3.floats``): ``R`` and
        ``omega`` the attitude and rate, ``R_d``, ``omega_d`` and ``omega_dot_d`` the reference's,
        ``h`` the array momentum (N m s). Returns the torque L_r, τ_fb, e_R, e_Ω and ``m = Rᵀ R_d``; the
        integral term advances by ``dt`` as in :meth:`update`. The control tick calls it with the floats
        it has (:attr:`Reference.floats`), without an array in or out."""
        # the control law of the module docstring term by term: numpy's per-call overhead on 3-vectors
        # was most of this once-per-tick cost
        w = wx, wy, wz = omega
        m = _transpose_matmul(R, R_d)  # Rᵀ R_d
        e_R = self._attitude_error(m)
        w_d = apply_f(m, omega_d)
        e_w = (wx - w_d[0], wy - w_d[1], wz - w_d[2])
        kr, ko = apply_f(self._K_R, e_R), apply_f(self._K_Omega, e_w)
        fb = (-kr[0] - ko[0], -kr[1] - ko[1], -kr[2] - ko[2])
        if self.gains.integral_time_s is not None:
            lim, t_i = self.gains.integral_limit, self.gains.integral_time_s
            ix, iy, iz = self.integral.tolist()
            i3 = (_clip(ix + dt * e_R[0], lim), _clip(iy + dt * e_R[1], lim), _clip(iz + dt * e_R[2], lim))
            if all(map(math.isfinite, i3)):  # a NaN estimate's tick once kept ∫e_R NaN for good
                self.integral = np.array(i3)
            else:  # this tick's torque is not finite anyway (steering gives no command); the next ones are
                i3 = (ix, iy, iz)
            ki = apply_f(self._K_R, i3)
            fb = (fb[0] - ki[0] / t_i, fb[1] - ki[1] / t_i, fb[2] - ki[2] / t_i)
        ax, ay, az = apply_f(m, omega_dot_d)
        cx, cy, cz = _cross(w, w_d)
        ff = apply_f(self._J, (ax - cx, ay - cy, az - cz))  # J (Rᵀ R_d Ω̇_d − Ω^× Rᵀ R_d Ω_d)
        fb = (fb[0] + ff[0], fb[1] + ff[1], fb[2] + ff[2])
        hx, hy, hz = h
        jx, jy, jz = apply_f(self._J, w)
        gx, gy, gz = _cross(w, (jx + hx, jy + hy, jz + hz))  # Ω × (J Ω + h)
        torque = (fb[0] + gx, fb[1] + gy, fb[2] + gz)
        return torque, fb, e_R, e_w, m


def _check_gain_matrices(K_R: Array, K_Omega: Array, gains: ControllerGains) -> None:
    """Refuse gains that are each valid but whose matrices at this inertia are not usable (a
    :class:`ConfigError` naming the gains): the torques they ask at a unit error — ``K_R`` times the
    largest weight (N m at an attitude error of ~1 rad), ``K_Ω`` (N m at 1 rad/s), the integral term's
    ``K_R · integral_limit / integral_time_s`` (N m) — at most steering's
    :data:`~hil.control.steering.TORQUE_SCALED_ABOVE`, beyond which steering treats every torque alike, and
    ``K_R``, ``K_Ω`` positive definite. Without this ω_n² J overflowed to inf (ω_n = 1e160: every torque
    NaN, inf · 0 at zero error), a huge weight times a huge K_R did so at a small error, and ω_n² J
    underflowed to 0 (ω_n = 1e-170: no attitude feedback at all): the control step steered with NaN, or
    nothing, for a controller."""
    k_r = float(np.max(np.abs(K_R)))  # Python floats: an overflow is inf, without numpy's warning
    asked = {
        "K_R (ω_n² J) times the largest weight": k_r * max(gains.weights),
        "K_Ω (2 ζ ω_n J)": float(np.max(np.abs(K_Omega))),
    }
    if gains.integral_time_s is not None:
        asked["K_R ∫e_R / T_i at the integral's limit"] = k_r * gains.integral_limit / gains.integral_time_s
    for what, torque in asked.items():
        if not torque <= TORQUE_SCALED_ABOVE:  # NaN and inf included
            raise ConfigError(
                f"{what} asks {torque:.3g} N m at a unit error, more than {TORQUE_SCALED_ABOVE:.0e}: "
                f"{gains!r}",
                "AttitudeController.gains",
            )
    for what, K in (("K_R = ω_n² J", K_R), ("K_Ω = 2 ζ ω_n J", K_Omega)):
        if not np.linalg.eigvalsh(0.5 * (K + K.T))[0] > 0:
            raise ConfigError(
                f"{what} is not positive definite at this inertia: {gains!r}", "AttitudeController.gains"
            )


def _transpose_matmul(p: Mat9, q: Mat9) -> Mat9:
    """``pᵀ q`` for row-major 9-tuples."""
    p0, p1, p2, p3, p4, p5, p6, p7, p8 = p
    return matmul_f((p0, p3, p6, p1, p4, p7, p2, p5, p8), q)


def _cross(a: Vec3, b: Vec3) -> Vec3:
    """``a × b`` (as ``np.cross``)."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _clip(x: float, lim: float) -> float:
    """``x`` clamped to [−lim, lim] (as ``np.clip``: NaN stays NaN, min and max returning it)."""
    return min(max(x, -lim), lim)


def _angle(m: Mat9) -> float:
    """The principal angle (rad, [0, π]) of the rotation ``m`` as :func:`hil.so3.principal_angle`."""
    x, y, z = 0.5 * (m[7] - m[5]), 0.5 * (m[2] - m[6]), 0.5 * (m[3] - m[1])
    return math.atan2(math.sqrt(x * x + y * y + z * z), (m[0] + m[4] + m[8] - 1.0) * 0.5)


@dataclass(frozen=True)
class EigenaxisSlew:
    """A rest-to-rest rotation from ``R0`` to ``R_f`` about their fixed eigenaxis in ``duration_s``, with the
    minimum-jerk profile ``θ(τ) = Θ (10τ³ − 15τ⁴ + 6τ⁵)``, τ = (t − start)/duration (peak rate
    1.875 Θ/T, peak acceleration 5.774 Θ/T²)."""

    R0: Array
    R_f: Array
    duration_s: float
    start_s: float = 0.0

    @classmethod
    def within_limits(
        cls, R0: ArrayLike, R_f: ArrayLike, max_rate: float, max_accel: float, start_s: float = 0.0
    ) -> EigenaxisSlew:
        """The quickest such slew whose peak rate (rad/s) and acceleration (rad/s²) stay within limits."""
        if not (max_rate > 0 and max_accel > 0):
            raise ConfigError("rate and acceleration limits must be positive", "EigenaxisSlew.within_limits")
        R0, R_f = np.asarray(R0, float), np.asarray(R_f, float)
        theta = so3.principal_angle(R0.T @ R_f)
        T = max(1.875 * theta / max_rate, math.sqrt(5.7735 * theta / max_accel), 1e-9)
        return cls(R0, R_f, T, start_s)

    @functools.cached_property
    def axis_angle(self) -> Array:
        """The body-frame rotation vector (3,) from R0 to R_f (computed once: :meth:`at` runs every
        control tick)."""
        return so3.log(np.asarray(self.R0).T @ np.asarray(self.R_f))

    @functools.cached_property
    def _floats(self) -> tuple[Mat9, Vec3]:
        """``R0`` as a row-major 9-tuple and :attr:`axis_angle` as a 3-tuple, for :meth:`at`'s float math."""
        return mat9(self.R0), vec3(self.axis_angle)

    def at(self, t: float) -> Reference:
        tau = min(max((t - self.start_s) / self.duration_s, 0.0), 1.0)
        r0, (px, py, pz) = self._floats
        s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau * tau)
        ds = 30.0 * tau * tau * (1.0 - tau) ** 2 / self.duration_s
        dds = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau) / self.duration_s**2
        # R0 exp(s φ^×) by Rodrigues on floats: one rotation a control tick, where numpy's overhead dominates
        R = matmul_f(r0, exp_f(s * px, s * py, s * pz))
        return Reference.of_floats(R, (ds * px, ds * py, ds * pz), (dds * px, dds * py, dds * pz))
