"""The estimator's parameters and the paper's constants: the potential's shaping function Φ
(:class:`Potential`), :class:`EstimatorParams` (E, W, m, D and the numerics, checked on construction), the
paper's E, W, m, D, Q0 and ω0, the inertial directions matrix ``E = [e1 e2 e1×e2]``
(:func:`directions_matrix`) and two initial attitudes (:func:`paper_initial_attitude`, :func:`wahba`).
Pure math, no I/O; the scheme these parameterise is in :mod:`hil.estimation.variational`."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil import so3
from protocol.errors import ConfigError

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Potential:
    """The shaping function Φ of the potential (C², Φ(0) = 0, Φ' > 0): the filter uses ``Φ'(U⁰)``.

    ``constant_derivative`` is set when Φ' does not depend on U⁰ (Φ linear), which spares computing U⁰;
    ``log_scale`` when Φ is :func:`phi_log`'s. The compiled estimator knows these two forms of Φ' only
    (:class:`EstimatorParams` refuses a potential with neither): ``value`` and ``derivative`` are what
    Python code (the numpy reference, plots) evaluates.
    """

    name: str
    value: Callable[[float], float]
    derivative: Callable[[float], float]
    constant_derivative: float | None = None
    log_scale: float | None = None


PHI_IDENTITY = Potential("identity", lambda x: x, lambda x: 1.0, 1.0)
"""The paper's choice, Φ(x) = x."""


def phi_log(scale: float) -> Potential:
    """``Φ(x) = s ln(1 + x/s)``: gain ``Φ' = 1/(1 + x/s)`` falls for large errors (less overshoot after a
    bad start or a disturbed magnetometer), and equals the identity's near convergence."""
    if not scale > 0:
        raise ConfigError(f"log potential scale must be positive, got {scale!r}", "phi_log")
    return Potential(
        f"log({scale:g})",
        lambda x: scale * math.log1p(x / scale),
        lambda x: 1.0 / (1.0 + x / scale),
        log_scale=float(scale),
    )


PAPER_E = ((0.0, 0.0772, -0.9921), (0.0, 0.6117, 0.1251), (1.0, -0.7873, 0.0))
PAPER_W = ((3.19, 1.51, 0.0), (1.51, 3.19, 0.0), (0.0, 0.0, 2.0))
PAPER_M = 0.5
PAPER_D = ((12.0, 0.0, 0.0), (0.0, 13.0, 0.0), (0.0, 0.0, 14.0))
PAPER_Q0_ROTVEC = (2.2 * 0.63, 2.2 * 0.62, -2.2 * 0.48)
"""Rotation vector of the paper's initial estimate error ``Q0 = R R̂ᵀ`` (≈127°)."""
PAPER_OMEGA0 = (0.001, 0.002, -0.003)
"""The paper's initial rate-estimate error ω0 (rad/s)."""


def directions_matrix(e_acc: ArrayLike, e_mag: ArrayLike) -> Array:
    """``E = [e1 e2 e1×e2/|e1×e2|]`` (3, 3) from the inertial directions of the accelerometer reading (up)
    and of the magnetic field; both are normalised. Raises ConfigError if they are (nearly) parallel."""
    e1 = _unit(e_acc, "e_acc")
    e2 = _unit(e_mag, "e_mag")
    c = np.cross(e1, e2)
    n = float(np.linalg.norm(c))
    if n < 1e-3:
        raise ConfigError("inertial directions are parallel: their cross product is undefined", "E")
    return np.column_stack([e1, e2, c / n])


def _unit(v: ArrayLike, where: str) -> Array:
    a = np.asarray(v, dtype=float).reshape(-1)
    n = float(np.linalg.norm(a)) if a.shape == (3,) else math.nan
    if not (math.isfinite(n) and n > 0):
        raise ConfigError(f"needs a non-zero finite 3-vector, got {v!r}", where)
    return a / n


def _matrix(value: ArrayLike, where: str) -> Array:
    a = np.asarray(value, dtype=float)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        raise ConfigError(f"must be a finite 3x3 matrix, got {np.asarray(value).tolist()!r}", where)
    if not np.allclose(a, a.T, rtol=0, atol=1e-12 * max(1.0, float(np.abs(a).max()))):
        raise ConfigError(f"must be symmetric, got {a.tolist()!r}", where)
    return a


@dataclass(frozen=True)
class EstimatorParams:
    """Gains and numerics of the estimator.

    ``E`` (3, 3): inertial (ENU) directions ``[e1 e2 e1×e2]`` — e1 the accelerometer's gravity reading
    (up), e2 the unit geomagnetic field; columns are normalised and the third is checked against (and
    replaced by) the normalised cross product. ``W`` (3, 3) symmetric weights: ``E W Eᵀ`` must be positive
    definite with distinct eigenvalues (U⁰ is then a Morse function on SO(3) with an almost-global basin).
    ``m`` > 0 (the estimator's 'inertia'), ``D`` (3, 3) symmetric positive definite (its 'dissipation').

    ``bias_gain`` (3,) ≥ 0: the diagonal of P⁻¹ in the gyro bias estimate's law ``db̂/dt = P⁻¹ Φ'(U⁰) S_L``
    (docs/estimator.md, "Gyro bias"; rad/s of bias per second per unit of torque); all zero (the paper's
    estimator) keeps b̂ at its initial value. ``bias_max`` (rad/s): each component of b̂ is kept within
    ±``bias_max`` (a projection, which never moves b̂ away from a true bias inside the bound).
    """

    E: Array = field(default_factory=lambda: np.array(PAPER_E))
    W: Array = field(default_factory=lambda: np.array(PAPER_W))
    m: float = PAPER_M
    D: Array = field(default_factory=lambda: np.array(PAPER_D))
    phi: Potential = PHI_IDENTITY
    newton_tol: float = 1e-12
    newton_max_iter: int = 10
    on_newton_failure: Literal["flag", "raise"] = "flag"
    max_step_s: float = 0.05
    min_direction_angle_deg: float = 2.0
    bias_gain: tuple[float, float, float] = (0.0, 0.0, 0.0)
    bias_max: float = math.inf
    gyro_delay_s: float = 0.0
    bias_vertical: float = 1.0

    def __post_init__(self) -> None:
        e = np.asarray(self.E, dtype=float)
        if e.shape != (3, 3) or not np.all(np.isfinite(e)):
            raise ConfigError("must be a finite 3x3 matrix of column directions", "EstimatorParams.E")
        norms = np.linalg.norm(e, axis=0)
        if np.any(np.abs(norms - 1.0) > 1e-2):
            raise ConfigError(f"columns must be unit vectors, norms are {norms.round(4).tolist()}", "E")
        e_full = directions_matrix(e[:, 0], e[:, 1])
        if np.linalg.norm(e_full[:, 2] - e[:, 2] / norms[2]) > 1e-2:
            expected = e_full[:, 2].round(4).tolist()
            raise ConfigError(f"third column {e[:, 2].tolist()} is not e1×e2/|e1×e2| = {expected}", "E")
        w = _matrix(self.W, "EstimatorParams.W")
        lam = np.linalg.eigvalsh(e_full @ w @ e_full.T)
        if lam[0] <= 0.0:
            raise ConfigError(f"E W Eᵀ must be positive definite; its eigenvalues are {lam.tolist()}", "W")
        if np.min(np.diff(lam)) <= 1e-6 * lam[-1]:
            raise ConfigError(
                f"E W Eᵀ must have distinct eigenvalues (else U⁰ is not a Morse function and the filter "
                f"has a continuum of equilibria); its eigenvalues are {lam.tolist()}",
                "W",
            )
        d = _matrix(self.D, "EstimatorParams.D")
        if np.linalg.eigvalsh(d)[0] <= 0.0:
            raise ConfigError(f"must be positive definite, eigenvalues {np.linalg.eigvalsh(d).tolist()}", "D")
        for name, ok in (
            ("m", math.isfinite(self.m) and self.m > 0),
            ("newton_tol", self.newton_tol > 0),
            ("newton_max_iter", self.newton_max_iter >= 1),
            ("max_step_s", self.max_step_s > 0),
            ("on_newton_failure", self.on_newton_failure in ("flag", "raise")),
            ("min_direction_angle_deg", 0 < self.min_direction_angle_deg < 90),
            ("bias_max", self.bias_max > 0),
            ("gyro_delay_s", math.isfinite(self.gyro_delay_s) and self.gyro_delay_s >= 0),
            ("bias_vertical", math.isfinite(self.bias_vertical) and self.bias_vertical >= 0.0),
        ):
            if not ok:
                raise ConfigError(f"invalid value {getattr(self, name)!r}", f"EstimatorParams.{name}")
        if self.phi.constant_derivative is None and self.phi.log_scale is None:
            raise ConfigError(
                f"potential {self.phi.name!r} has no compiled form: use PHI_IDENTITY, phi_log(s) or a "
                "Potential with a constant_derivative",
                "EstimatorParams.phi",
            )
        gain = np.broadcast_to(np.asarray(self.bias_gain, dtype=float), (3,))
        if not np.all(np.isfinite(gain) & (gain >= 0.0)):
            raise ConfigError(f"must be finite and >= 0, got {self.bias_gain!r}", "EstimatorParams.bias_gain")
        object.__setattr__(self, "bias_gain", tuple(float(x) for x in gain))
        object.__setattr__(self, "E", e_full)
        object.__setattr__(self, "W", w)
        object.__setattr__(self, "D", d)
        object.__setattr__(self, "m", float(self.m))

    @classmethod
    def paper(cls, **overrides: object) -> EstimatorParams:
        """The paper's experiment: its E (ENU), W, m = 0.5, D = diag(12, 13, 14), Φ(x) = x."""
        return cls(**overrides)  # type: ignore[arg-type]


def paper_initial_attitude(r_true: ArrayLike) -> Array:
    """The paper's initial estimate for a true attitude ``R``: ``R̂0 = Q0ᵀ R`` with ``Q0 = R R̂0ᵀ`` ≈ 127°."""
    return so3.exp(PAPER_Q0_ROTVEC).T @ np.asarray(r_true, dtype=float)


def wahba(params: EstimatorParams, acc: ArrayLike, mag: ArrayLike) -> Array:
    """The attitude minimising the potential U⁰ for one pair of measurements (Wahba's problem, by SVD of
    ``L = E W Uᵀ``): the natural initial estimate for a real log. Body → inertial, (3, 3)."""
    u1, u2 = _unit(acc, "acc"), _unit(mag, "mag")
    c = np.cross(u1, u2)
    u = np.column_stack([u1, u2, c / np.linalg.norm(c)])
    b = params.E @ params.W @ u.T
    left, _, right_t = np.linalg.svd(b)
    d = np.sign(np.linalg.det(left) * np.linalg.det(right_t))
    return left @ np.diag([1.0, 1.0, d]) @ right_t
