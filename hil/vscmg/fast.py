"""The plant for one run in plain Python floats: the same RKMK4 step as :meth:`Plant.step`, for B = 1.

:class:`Plant` is vectorised over a batch axis; for a single spacecraft (the emulator's world, stepped
every millisecond next to its board) its cost is numpy's per-call overhead, not arithmetic: ~700 numpy
calls of a few µs for ~5000 floating-point operations. :class:`SingleRunPlant` does the same arithmetic on
Python floats, unit by unit, with nothing allocated but a few tuples: configuration (gimbal frames, locked
inertia J, the mass matrix's columns b_γ, b_φ and 2×2 block inverses, the rotor inertia turned by φ for
non-axisymmetric rotors), velocities (the 3×3 Schur complement solved by its adjugate), body rates and
gyroscopic forces, the gravity-gradient moment, Rodrigues' exp, dexp⁻¹ and the final Newton–Schulz
correction, in the order :meth:`Plant.step` takes them. Results agree with the numpy plant to rounding
(tests/test_vscmg_fast.py: ~1e-13 relative after thousands of steps).

Its state, :class:`FastState`, holds floats and tuples; :meth:`SingleRunPlant.to_state` and
:meth:`SingleRunPlant.from_state` convert to and from :class:`PlantState` (batch 1) at the boundary, so a
caller that only needs the attitude and rates each step does not pay for arrays it does not read.

Torques: None, a constant ``(gimbal, rotor)`` pair, a law with a scalar form (``scalar_setpoints()`` and
``torques_scalar(gimbal_rate, rotor_rate, gimbal_load, rotor_load, setpoints)`` on sequences of floats, as
:class:`hil.control.motor_loops.ServoModel` has), or any other :data:`TorqueLaw`, called with (1, n) arrays.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable, Iterable, Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from hil.so3 import Mat9, Vec3, exp_f, matmul_f, reorthonormalize_f
from protocol.errors import ConfigError, NumericalError

from .plant import Plant, PlantState, Torques

Array = NDArray[np.float64]

_TWO_PI = 2.0 * math.pi
_cos, _sin, _sqrt, _isfinite = math.cos, math.sin, math.sqrt, math.isfinite
_add = operator.add


@runtime_checkable
class ScalarTorqueLaw(Protocol):
    """A torque law with a float form for a single run (what :class:`hil.control.motor_loops.ServoModel`
    offers):
    ``scalar_setpoints()`` the held inputs, read once per step; ``torques_scalar(...)`` the torques
    ``(gimbal, rotor)`` (n floats each) at one stage, exactly what calling the law with arrays gives."""

    def scalar_setpoints(self) -> Any: ...

    def torques_scalar(
        self,
        gimbal_rate: Sequence[float],
        rotor_rate: Sequence[float],
        gimbal_load: Sequence[float],
        rotor_load: Sequence[float],
        setpoints: Any = None,
    ) -> tuple[Sequence[float], Sequence[float]]: ...


class FastState:
    """One run's plant state in floats: ``t`` (s), ``R`` (9-tuple, row-major, body → inertial), ``x`` the
    integrated variables as :meth:`Plant.step` stacks them, ``[π (3), γ (n), φ (n), p_γ (n), p_φ (n)]``,
    and the derived velocities ``omega`` (3-tuple), ``gimbal_rate`` and ``rotor_rate`` (n floats).
    Treat it as immutable (steps return new states)."""

    __slots__ = ("t", "R", "x", "omega", "gimbal_rate", "rotor_rate", "n", "cache")

    def __init__(
        self,
        t: float,
        R: Mat9,
        x: Sequence[float],
        omega: Sequence[float],
        gimbal_rate: Sequence[float],
        rotor_rate: Sequence[float],
        cache: Any = None,
    ) -> None:
        self.t = t
        self.R = R
        self.x = x
        self.omega = omega
        self.gimbal_rate = gimbal_rate
        self.rotor_rate = rotor_rate
        self.n = len(gimbal_rate)
        self.cache = cache  # the stepper's geometry at this state (its first stage reuses it), or None

    @property
    def momentum(self) -> Sequence[float]:
        return self.x[0:3]

    @property
    def gimbal_angle(self) -> Sequence[float]:
        return self.x[3 : 3 + self.n]

    @property
    def rotor_angle(self) -> Sequence[float]:
        return self.x[3 + self.n : 3 + 2 * self.n]

    @property
    def gimbal_momentum(self) -> Sequence[float]:
        return self.x[3 + 2 * self.n : 3 + 3 * self.n]

    @property
    def rotor_momentum(self) -> Sequence[float]:
        return self.x[3 + 3 * self.n :]

    def R_matrix(self) -> Array:
        """``R`` as a (3, 3) array."""
        return np.array(self.R, dtype=float).reshape(3, 3)

    def omega_array(self) -> Array:
        """``omega`` as a (3,) array."""
        return np.array(self.omega, dtype=float)


def _unit_forces(
    v0: float, v1: float, v2: float, w_rate: float, inertia: Sequence[float]
) -> tuple[float, float]:
    """One unit's ``(∂T/∂γ, ∂T/∂φ)`` (:func:`model.internal_forces`) from its gimbal's angular velocity
    ``ω_G = (v0, v1, v2)`` (gimbal frame, γ̇ included) and rotor rate φ̇: ``ω_W = ω_G + φ̇ e_s``, ``h = Ī ω``.
    ``inertia``: the gimbal's first two rows (6) then the rotor's 3×3 (9), gimbal-frame components."""
    g00, g01, g02, g10, g11, g12, w00, w01, w02, w10, w11, w12, w20, w21, w22 = inertia
    q0 = v0 + w_rate
    hg0 = g00 * v0 + g01 * v1 + g02 * v2
    hg1 = g10 * v0 + g11 * v1 + g12 * v2
    hw0 = w00 * q0 + w01 * v1 + w02 * v2
    hw1 = w10 * q0 + w11 * v1 + w12 * v2
    hw2 = w20 * q0 + w21 * v1 + w22 * v2
    return -(v0 * hg1 - v1 * hg0) - (q0 * hw1 - v1 * hw0) + w_rate * hw1, -(v1 * hw2 - v2 * hw1)


class SingleRunPlant:
    """:class:`Plant`'s step for one run in Python floats. Built from a plant (its :class:`ArrayModel` and
    gravity): ``plant.model`` must describe one spacecraft (shared parameters, or per-run parameters of a
    batch of 1). :meth:`step` on :class:`FastState`; :meth:`step_state` and :meth:`run` on
    :class:`PlantState` for callers that want the reference's interface.

    Axisymmetric rotors (Ī_W^G, K̄ and D⁻¹ constant) take a shorter road to the same numbers: with
    ``C = C₀ Rz(γ)`` (C₀ = [s₀ t₀ g]) every per-unit matrix ``C A Cᵀ`` of a constant gimbal-frame ``A`` is
    ``P₀ + P₁ cos 2γ + P₂ sin 2γ + P₃ cos γ + P₄ sin γ`` with the ``Pₖ`` computed once. The Schur complement
    ``J − Σ B D⁻¹ Bᵀ = J₀ + Σ C L Cᵀ``, ``L = K̄ − E D⁻¹ Eᵀ`` (E = [K̄ e_g, Ī_W e_s], ``L e_g = 0``: a
    free gimbal carries no moment about its axis, so only the 2γ terms remain), is summed that way,
    and ``b·Ω = e·(Cᵀ Ω)`` needs no body-frame columns at all. Non-axisymmetric rotors take the reference's
    road (configuration, Schur complement, solve), term by term."""

    def __init__(self, plant: Plant) -> None:
        m = plant.model
        if m.batch not in (None, 1):
            raise ConfigError(f"needs one run's parameters, the plant has {m.batch}", "SingleRunPlant")

        def one(a: Array) -> Array:
            return a[0] if m.batch is not None else a

        self.plant = plant
        self.n = n = m.n
        self.axisymmetric = m.axisymmetric
        g, s0, t0 = one(m.g), one(m.s0), one(m.t0)
        IG, IW, K, dinv = one(m.IG), one(m.IW), one(m.K), one(m.dinv)
        J0 = one(m.J0)
        self._J0: Mat9 = _t9(J0)
        # general road, per unit: s₀, t₀, g (9 floats); rotor inertias (a, b, c, d, e, f) upper triangle
        self._axes = [tuple(s0[i].tolist() + t0[i].tolist() + g[i].tolist()) for i in range(n)]
        self._ig = [_t9(IG[i]) for i in range(n)]
        self._iw = [tuple(float(IW[i][r, c]) for r, c in _UPPER) for i in range(n)]
        # axisymmetric road, per unit: Schur basis (P₁, P₂) of L (2 × 6), locked-inertia basis (P₁, P₂) and
        # (P₃, P₄) of K̄ (2 × 6 each, the second None when zero: no products of inertia coupling g to s
        # and t), (e_γ, e_φ, D⁻¹) (9), (Ī_G rows s, t; Ī_W) (15)
        self._ax_S: list[tuple[float, ...]] = []
        self._ax_J: list[tuple[tuple[float, ...], tuple[float, ...] | None]] = []
        self._ax_E: list[tuple[float, ...]] = []
        self._ax_F: list[tuple[float, ...]] = []
        S0, JK0 = J0.copy(), J0.copy()
        if m.axisymmetric:
            for i in range(n):
                C0 = np.column_stack([s0[i], t0[i], g[i]])
                k, w, d = K[i], IW[i], dinv[i]
                E = np.column_stack([k[:, 2], w[:, 0]])
                L = k - E @ np.array([[d[0], d[1]], [d[1], d[2]]]) @ E.T
                # a free gimbal carries no moment about g: L e_g = K̄ e_g − E D⁻¹ (D e₁) = 0 (to rounding),
                # so C L Cᵀ has no terms in cos γ, sin γ
                L[2, :] = L[:, 2] = 0.0
                PL, PK = _turn_basis(C0, L), _turn_basis(C0, k)
                S0 += PL[0]
                JK0 += PK[0]
                self._ax_S.append(_sym6(PL[1]) + _sym6(PL[2]))
                self._ax_J.append(_turn_terms(PK))
                self._ax_E.append(tuple(E[:, 0].tolist() + E[:, 1].tolist() + d.tolist()))
                self._ax_F.append(_t9(IG[i])[:6] + _t9(w))
        self._S0 = _sym6(S0)
        self._JK0 = _sym6(JK0)
        gr = plant.gravity
        if gr is not None:
            q = np.cross(np.asarray(gr.orbit_normal, float), np.asarray(gr.radial_at_epoch, float))
            self._gravity: tuple[float, float, tuple[float, ...], tuple[float, ...]] | None = (
                gr.mean_motion,
                3.0 * gr.mean_motion**2,
                tuple(float(v) for v in gr.radial_at_epoch),
                tuple(q.tolist()),
            )
        else:
            self._gravity = None

    # ------------------------------------------------------------------ conversions
    def from_state(self, s: PlantState, index: int = 0) -> FastState:
        """Run ``index`` of ``s`` as a :class:`FastState`."""
        if s.gimbal_angle.shape[-1] != self.n:
            raise ConfigError(f"the state has {s.gimbal_angle.shape[-1]} units, not {self.n}", "FastState")
        i = index
        x = (
            s.momentum[i].tolist()
            + s.gimbal_angle[i].tolist()
            + s.rotor_angle[i].tolist()
            + s.gimbal_momentum[i].tolist()
            + s.rotor_momentum[i].tolist()
        )
        return FastState(
            float(s.t),
            tuple(s.R[i].ravel().tolist()),
            x,
            tuple(s.omega[i].tolist()),
            s.gimbal_rate[i].tolist(),
            s.rotor_rate[i].tolist(),
        )

    def to_state(self, f: FastState) -> PlantState:
        """``f`` as a :class:`PlantState` of batch 1."""
        n, x = self.n, f.x
        return PlantState(
            f.t,
            np.array(f.R, dtype=float).reshape(1, 3, 3),
            np.array([x[0:3]], dtype=float),
            np.array([x[3 : 3 + n]], dtype=float),
            np.array([x[3 + n : 3 + 2 * n]], dtype=float),
            np.array([x[3 + 2 * n : 3 + 3 * n]], dtype=float),
            np.array([x[3 + 3 * n :]], dtype=float),
            np.array([f.omega], dtype=float),
            np.array([f.gimbal_rate], dtype=float),
            np.array([f.rotor_rate], dtype=float),
        )

    # ------------------------------------------------------------------ stepping
    def step_state(self, s: PlantState, dt: float, torques: Torques = None) -> PlantState:
        """:meth:`Plant.step` for a state of batch 1 (converting at both ends)."""
        if s.batch != 1:
            raise ConfigError(f"steps one run, the state has {s.batch}", "SingleRunPlant.step_state")
        return self.to_state(self.step(self.from_state(s), dt, torques))

    def run(
        self,
        s: PlantState,
        dt: float,
        n_steps: int,
        torques: Torques = None,
        observe: Callable[[PlantState], None] | None = None,
    ) -> PlantState:
        """:meth:`Plant.run` for a state of batch 1."""
        if s.batch != 1:
            raise ConfigError(f"steps one run, the state has {s.batch}", "SingleRunPlant.run")
        f = self.from_state(s)
        for _ in range(n_steps):
            f = self.step(f, dt, torques)
            if observe is not None:
                observe(self.to_state(f))
        return self.to_state(f)

    def step(self, s: FastState, dt: float, torques: Torques = None) -> FastState:
        """Advance ``s`` by ``dt`` seconds (RKMK4, as :meth:`Plant.step`) under ``torques``; raises
        NumericalError if the state stops being finite or the torques are not finite."""
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ConfigError(f"must be a positive step, got {dt!r}", "SingleRunPlant.step.dt")
        mode, arg = self._torque_mode(torques)
        try:
            return self._step(s, dt, mode, arg)
        except (OverflowError, ZeroDivisionError, ValueError) as e:  # floats raise where numpy makes inf/nan
            if isinstance(e, ValueError) and "math domain error" not in str(e):
                raise
            raise NumericalError(
                f"the plant state diverged at t = {s.t + dt:.6g} s (step {dt:g} s too long?)"
            ) from e

    def _step(self, s: FastState, h: float, mode: int, arg: Any) -> FastState:
        n, t0 = self.n, s.t
        x0, R0 = s.x, s.R
        deriv = self._derivative
        hh = 0.5 * h
        w1, f1 = deriv(t0, R0, x0, mode, arg, (s.omega, s.gimbal_rate, s.rotor_rate), s.cache)
        th2 = (hh * w1[0], hh * w1[1], hh * w1[2])
        w2, f2 = deriv(
            t0 + hh, matmul_f(R0, exp_f(*th2)), [a + hh * b for a, b in zip(x0, f1, strict=True)], mode, arg
        )
        d2 = _dexpinv(th2, w2)
        th3 = (hh * d2[0], hh * d2[1], hh * d2[2])
        w3, f3 = deriv(
            t0 + hh, matmul_f(R0, exp_f(*th3)), [a + hh * b for a, b in zip(x0, f2, strict=True)], mode, arg
        )
        d3 = _dexpinv(th3, w3)
        th4 = (h * d3[0], h * d3[1], h * d3[2])
        w4, f4 = deriv(
            t0 + h, matmul_f(R0, exp_f(*th4)), [a + h * b for a, b in zip(x0, f3, strict=True)], mode, arg
        )
        d4 = _dexpinv(th4, w4)
        h6 = h / 6.0
        th = (
            h6 * (w1[0] + 2.0 * d2[0] + 2.0 * d3[0] + d4[0]),
            h6 * (w1[1] + 2.0 * d2[1] + 2.0 * d3[1] + d4[1]),
            h6 * (w1[2] + 2.0 * d2[2] + 2.0 * d3[2] + d4[2]),
        )
        R = reorthonormalize_f(matmul_f(R0, exp_f(*th)))
        x = [a + h6 * (b + 2.0 * c + 2.0 * d + e) for a, b, c, d, e in zip(x0, f1, f2, f3, f4, strict=True)]
        if not _isfinite(sum(x)) and not all(map(_isfinite, x)):
            raise NumericalError(f"the plant state diverged at t = {t0 + h:.6g} s (step {h:g} s too long?)")
        for i in range(3 + n, 3 + 2 * n):
            x[i] = x[i] % _TWO_PI
        r0, r1, r2, r3, r4, r5, r6, r7, r8 = R
        p0, p1, p2 = x[0], x[1], x[2]
        H = (r0 * p0 + r3 * p1 + r6 * p2, r1 * p0 + r4 * p1 + r7 * p2, r2 * p0 + r5 * p1 + r8 * p2)
        ga, pg, pp = x[3 : 3 + n], x[3 + 2 * n : 3 + 3 * n], x[3 + 3 * n :]
        cache: Any
        if self.axisymmetric:
            omega, gr, wr, trig, vs = self._solve_axisymmetric(ga, H, pg, pp)
            cache = (trig, vs)
        else:
            geo, J = self._configuration(ga, x[3 + n : 3 + 2 * n], True)
            assert J is not None
            omega, gr, wr = self._velocities(geo, J, H, pg, pp)
            cache = (geo, J)
        return FastState(t0 + h, R, x, omega, gr, wr, cache)

    # ------------------------------------------------------------------ internals
    def _torque_mode(self, torques: Torques) -> tuple[int, Any]:
        """How a step gets its torques: 0 none, 1 a constant pair (lists), 2 a scalar law and its held
        setpoints, 3 any other law (arrays)."""
        if torques is None:
            return 0, None
        if callable(getattr(torques, "torques_scalar", None)):  # a ScalarTorqueLaw (a cheap test)
            law: Any = torques
            return 2, (law, law.scalar_setpoints())
        if callable(torques):
            return 3, torques
        n = self.n
        ug = np.broadcast_to(np.asarray(torques[0], float), (1, n))[0].tolist()
        us = np.broadcast_to(np.asarray(torques[1], float), (1, n))[0].tolist()
        return 1, (ug, us)

    def _derivative(
        self,
        t: float,
        R: Mat9,
        x: Sequence[float],
        mode: int,
        arg: Any,
        known: tuple[Sequence[float], Sequence[float], Sequence[float]] | None = None,
        cache: Any = None,
    ) -> tuple[Sequence[float], list[float]]:
        """``(Ω, ẋ)`` at one stage (:meth:`Plant._derivative`); ``known`` velocities skip the solve and
        ``cache`` (the geometry the last step left at this state) the geometry."""
        n = self.n
        grav = self._gravity
        ga = x[3 : 3 + n]
        J: Sequence[float] | None = None
        omega: Sequence[float]
        gr: Sequence[float]
        wr: Sequence[float]
        if known is None:
            p0, p1, p2 = x[0], x[1], x[2]
            H = (
                R[0] * p0 + R[3] * p1 + R[6] * p2,
                R[1] * p0 + R[4] * p1 + R[7] * p2,
                R[2] * p0 + R[5] * p1 + R[8] * p2,
            )
        if self.axisymmetric:
            if known is None:
                omega, gr, wr, trig, vs = self._solve_axisymmetric(
                    ga, H, x[3 + 2 * n : 3 + 3 * n], x[3 + 3 * n :]
                )
            else:
                omega, gr, wr = known
                trig, vs = cache if cache is not None else self._gimbal_frame_rates(ga, omega)
            fg, fp = self._forces_axisymmetric(vs, gr, wr)
            if grav is not None:
                J = self._locked_inertia_axisymmetric(trig)
        else:
            if known is None:
                geo, J = self._configuration(ga, x[3 + n : 3 + 2 * n], True)
                assert J is not None
                omega, gr, wr = self._velocities(geo, J, H, x[3 + 2 * n : 3 + 3 * n], x[3 + 3 * n :])
            else:
                omega, gr, wr = known
                geo, J = (
                    cache
                    if cache is not None
                    else self._configuration(ga, x[3 + n : 3 + 2 * n], grav is not None)
                )
            fg, fp = self._forces(geo, omega, gr, wr)
        gimbal: Iterable[float] = fg
        rotor: Iterable[float] = fp
        if mode:
            if mode == 2:
                law, sp = arg
                ug, us = law.torques_scalar(gr, wr, fg, fp, sp)
            elif mode == 1:
                ug, us = arg
            else:
                ug_a, us_a = arg(
                    t,
                    np.array([ga], dtype=float),
                    np.array([gr], dtype=float),
                    np.array([wr], dtype=float),
                    np.array([fg], dtype=float),
                    np.array([fp], dtype=float),
                )
                ug = np.broadcast_to(np.asarray(ug_a, float), (1, n))[0].tolist()
                us = np.broadcast_to(np.asarray(us_a, float), (1, n))[0].tolist()
            if not _isfinite(sum(ug) + sum(us)) and not (all(map(_isfinite, ug)) and all(map(_isfinite, us))):
                raise NumericalError(
                    f"non-finite motor torque at t = {t:.6g} s: gimbal {list(ug)}, rotor {list(us)}"
                )
            if len(ug) != n or len(us) != n:
                raise ConfigError(f"needs {n} gimbal and rotor torques", "SingleRunPlant.torques")
            gimbal = map(_add, fg, ug)
            rotor = map(_add, fp, us)
        if grav is not None:
            assert J is not None
            dpi = _gravity_gradient(grav, t, R, J)
        else:
            dpi = (0.0, 0.0, 0.0)
        return omega, [*dpi, *gr, *wr, *gimbal, *rotor]

    # ---------------------------------------------------------- axisymmetric rotors
    def _solve_axisymmetric(
        self, ga: Sequence[float], H: Vec3, pg: Sequence[float], pp: Sequence[float]
    ) -> tuple[Vec3, list[float], list[float], list[tuple[float, float]], list[Vec3]]:
        """Velocities ``(Ω, γ̇, φ̇)`` from the momenta at gimbal angles ``ga``, with each unit's
        ``(cos γ, sin γ)`` and gimbal-frame body rate ``Cᵀ Ω`` (no γ̇) for the forces."""
        s00, s01, s02, s11, s12, s22 = self._S0
        h0, h1, h2 = H
        trig = []
        for P, ax, E, gamma, p_g, p_p in zip(self._ax_S, self._axes, self._ax_E, ga, pg, pp, strict=True):
            c, s = _cos(gamma), _sin(gamma)
            c2, s2 = c * c - s * s, 2.0 * c * s
            a00, a01, a02, a11, a12, a22, b00, b01, b02, b11, b12, b22 = P
            s00 += c2 * a00 + s2 * b00
            s01 += c2 * a01 + s2 * b01
            s02 += c2 * a02 + s2 * b02
            s11 += c2 * a11 + s2 * b11
            s12 += c2 * a12 + s2 * b12
            s22 += c2 * a22 + s2 * b22
            # rhs −= C E D⁻¹ (p_γ, p_φ)
            u0, u1, u2, w0, w1, w2, i11, i12, i22 = E
            al, be = i11 * p_g + i12 * p_p, i12 * p_g + i22 * p_p
            y0, y1, y2 = u0 * al + w0 * be, u1 * al + w1 * be, u2 * al + w2 * be
            z0, z1 = c * y0 - s * y1, s * y0 + c * y1
            sx, sy, sz, tx, ty, tz, gx, gy, gz = ax
            h0 -= sx * z0 + tx * z1 + gx * y2
            h1 -= sy * z0 + ty * z1 + gy * y2
            h2 -= sz * z0 + tz * z1 + gz * y2
            trig.append((c, s))
        # the symmetric 3×3 solve by its adjugate
        c00 = s11 * s22 - s12 * s12
        c01 = s12 * s02 - s01 * s22
        c02 = s01 * s12 - s11 * s02
        det = s00 * c00 + s01 * c01 + s02 * c02
        if det == 0.0:
            raise NumericalError("singular VSCMG mass matrix")
        c11 = s00 * s22 - s02 * s02
        c12 = s02 * s01 - s00 * s12
        c22 = s00 * s11 - s01 * s01
        o0 = (c00 * h0 + c01 * h1 + c02 * h2) / det
        o1 = (c01 * h0 + c11 * h1 + c12 * h2) / det
        o2 = (c02 * h0 + c12 * h1 + c22 * h2) / det
        gr, wr, vs = [], [], []
        for ax, E, (c, s), p_g, p_p in zip(self._axes, self._ax_E, trig, pg, pp, strict=True):
            sx, sy, sz, tx, ty, tz, gx, gy, gz = ax
            u0, u1, u2, w0, w1, w2, i11, i12, i22 = E
            vs0, vt0 = sx * o0 + sy * o1 + sz * o2, tx * o0 + ty * o1 + tz * o2
            v0, v1, v2 = c * vs0 + s * vt0, c * vt0 - s * vs0, gx * o0 + gy * o1 + gz * o2
            rg = p_g - (u0 * v0 + u1 * v1 + u2 * v2)
            rp = p_p - (w0 * v0 + w1 * v1 + w2 * v2)
            gr.append(i11 * rg + i12 * rp)
            wr.append(i12 * rg + i22 * rp)
            vs.append((v0, v1, v2))
        return (o0, o1, o2), gr, wr, trig, vs

    def _gimbal_frame_rates(
        self, ga: Sequence[float], omega: Sequence[float]
    ) -> tuple[list[tuple[float, float]], list[Vec3]]:
        """Each unit's ``(cos γ, sin γ)`` and ``Cᵀ Ω``."""
        o0, o1, o2 = omega
        trig, vs = [], []
        for ax, gamma in zip(self._axes, ga, strict=True):
            c, s = _cos(gamma), _sin(gamma)
            sx, sy, sz, tx, ty, tz, gx, gy, gz = ax
            vs0, vt0 = sx * o0 + sy * o1 + sz * o2, tx * o0 + ty * o1 + tz * o2
            trig.append((c, s))
            vs.append((c * vs0 + s * vt0, c * vt0 - s * vs0, gx * o0 + gy * o1 + gz * o2))
        return trig, vs

    def _forces_axisymmetric(
        self, vs: list[Vec3], gr: Sequence[float], wr: Sequence[float]
    ) -> tuple[list[float], list[float]]:
        """``(∂T/∂γ, ∂T/∂φ)`` from each unit's ``Cᵀ Ω`` and its rates (:func:`model.internal_forces`)."""
        fg, fp = [], []
        for F, (v0, v1, v2), g_rate, w_rate in zip(self._ax_F, vs, gr, wr, strict=True):
            f_gamma, f_phi = _unit_forces(v0, v1, v2 + g_rate, w_rate, F)
            fg.append(f_gamma)
            fp.append(f_phi)
        return fg, fp

    def _locked_inertia_axisymmetric(self, trig: list[tuple[float, float]]) -> Mat9:
        """J(γ) (row-major) from each unit's ``(cos γ, sin γ)``."""
        j00, j01, j02, j11, j12, j22 = self._JK0
        for (P2, P1), (c, s) in zip(self._ax_J, trig, strict=True):
            c2, s2 = c * c - s * s, 2.0 * c * s
            a00, a01, a02, a11, a12, a22, b00, b01, b02, b11, b12, b22 = P2
            j00 += c2 * a00 + s2 * b00
            j01 += c2 * a01 + s2 * b01
            j02 += c2 * a02 + s2 * b02
            j11 += c2 * a11 + s2 * b11
            j12 += c2 * a12 + s2 * b12
            j22 += c2 * a22 + s2 * b22
            if P1 is not None:
                a00, a01, a02, a11, a12, a22, b00, b01, b02, b11, b12, b22 = P1
                j00 += c * a00 + s * b00
                j01 += c * a01 + s * b01
                j02 += c * a02 + s * b02
                j11 += c * a11 + s * b11
                j12 += c * a12 + s * b12
                j22 += c * a22 + s * b22
        return (j00, j01, j02, j01, j11, j12, j02, j12, j22)

    # ---------------------------------------------------------- any rotor (the reference's road)
    def _configuration(
        self, ga: Sequence[float], ra: Sequence[float], want_j: bool
    ) -> tuple[list[tuple[float, ...]], Mat9 | None]:
        """Per unit ``(s (3), t (3), g (3), Ī_W^G (9), b_γ (3), b_φ (3), D⁻¹ (3))`` at gimbal angles
        ``ga`` and rotor angles ``ra``, and the locked inertia J (when ``want_j``)."""
        geo: list[tuple[float, ...]] = []
        j00 = j01 = j02 = j10 = j11 = j12 = j20 = j21 = j22 = 0.0
        for k, gamma in enumerate(ga):
            c, s = _cos(gamma), _sin(gamma)
            s0x, s0y, s0z, t0x, t0y, t0z, gx, gy, gz = self._axes[k]
            a, b, cc, d, e, f = self._iw[k]
            cp, sp = _cos(ra[k]), _sin(ra[k])
            w00 = a
            w01 = w10 = b * cp - cc * sp
            w02 = w20 = b * sp + cc * cp
            w11 = cp * cp * d - 2.0 * cp * sp * e + sp * sp * f
            w12 = w21 = cp * sp * (d - f) + (cp * cp - sp * sp) * e
            w22 = sp * sp * d + 2.0 * cp * sp * e + cp * cp * f
            g00, g01, g02, g10, g11, g12, g20, g21, g22 = self._ig[k]
            k00, k01, k02 = g00 + w00, g01 + w01, g02 + w02
            k10, k11, k12 = g10 + w10, g11 + w11, g12 + w12
            k20, k21, k22 = g20 + w20, g21 + w21, g22 + w22
            det = k22 * w00 - w20 * w20
            i11, i12, i22 = w00 / det, -w20 / det, k22 / det
            # C = [s t g] (columns), rows (a_r, b_r, g_r)
            a0, a1, a2 = c * s0x + s * t0x, c * s0y + s * t0y, c * s0z + s * t0z
            b0, b1, b2 = c * t0x - s * s0x, c * t0y - s * s0y, c * t0z - s * s0z
            # M = C K̄
            m02 = a0 * k02 + b0 * k12 + gx * k22
            m12 = a1 * k02 + b1 * k12 + gy * k22
            m22 = a2 * k02 + b2 * k12 + gz * k22
            if want_j:
                m00 = a0 * k00 + b0 * k10 + gx * k20
                m01 = a0 * k01 + b0 * k11 + gx * k21
                m10 = a1 * k00 + b1 * k10 + gy * k20
                m11 = a1 * k01 + b1 * k11 + gy * k21
                m20 = a2 * k00 + b2 * k10 + gz * k20
                m21 = a2 * k01 + b2 * k11 + gz * k21
                # J += M Cᵀ
                j00 += m00 * a0 + m01 * b0 + m02 * gx
                j01 += m00 * a1 + m01 * b1 + m02 * gy
                j02 += m00 * a2 + m01 * b2 + m02 * gz
                j10 += m10 * a0 + m11 * b0 + m12 * gx
                j11 += m10 * a1 + m11 * b1 + m12 * gy
                j12 += m10 * a2 + m11 * b2 + m12 * gz
                j20 += m20 * a0 + m21 * b0 + m22 * gx
                j21 += m20 * a1 + m21 * b1 + m22 * gy
                j22 += m20 * a2 + m21 * b2 + m22 * gz
            geo.append(
                (
                    a0, a1, a2, b0, b1, b2, gx, gy, gz,
                    w00, w01, w02, w10, w11, w12, w20, w21, w22,
                    m02, m12, m22,
                    a0 * w00 + b0 * w10 + gx * w20,
                    a1 * w00 + b1 * w10 + gy * w20,
                    a2 * w00 + b2 * w10 + gz * w20,
                    i11, i12, i22,
                )
            )  # fmt: skip
        if not want_j:
            return geo, None
        J0 = self._J0
        J: Mat9 = (
            J0[0] + j00, J0[1] + j01, J0[2] + j02,
            J0[3] + j10, J0[4] + j11, J0[5] + j12,
            J0[6] + j20, J0[7] + j21, J0[8] + j22,
        )  # fmt: skip
        return geo, J

    @staticmethod
    def _velocities(
        geo: list[tuple[float, ...]],
        J: Mat9,
        H: Vec3,
        pg: Sequence[float],
        pp: Sequence[float],
    ) -> tuple[Vec3, list[float], list[float]]:
        """Solve ``M ν = (Π, p_γ, p_φ)`` (:func:`hil.vscmg.model.velocities`): each unit's 2×2 block
        eliminated, the 3×3 Schur complement solved by its adjugate."""
        s00, s01, s02, s10, s11, s12, s20, s21, s22 = J
        h0, h1, h2 = H
        for u, p_g, p_p in zip(geo, pg, pp, strict=True):
            bg0, bg1, bg2, bp0, bp1, bp2, i11, i12, i22 = u[18:27]
            ug0, ug1, ug2 = i11 * bg0 + i12 * bp0, i11 * bg1 + i12 * bp1, i11 * bg2 + i12 * bp2
            up0, up1, up2 = i12 * bg0 + i22 * bp0, i12 * bg1 + i22 * bp1, i12 * bg2 + i22 * bp2
            s00 -= ug0 * bg0 + up0 * bp0
            s01 -= ug0 * bg1 + up0 * bp1
            s02 -= ug0 * bg2 + up0 * bp2
            s10 -= ug1 * bg0 + up1 * bp0
            s11 -= ug1 * bg1 + up1 * bp1
            s12 -= ug1 * bg2 + up1 * bp2
            s20 -= ug2 * bg0 + up2 * bp0
            s21 -= ug2 * bg1 + up2 * bp1
            s22 -= ug2 * bg2 + up2 * bp2
            h0 -= ug0 * p_g + up0 * p_p
            h1 -= ug1 * p_g + up1 * p_p
            h2 -= ug2 * p_g + up2 * p_p
        c00 = s11 * s22 - s12 * s21
        c01 = s12 * s20 - s10 * s22
        c02 = s10 * s21 - s11 * s20
        det = s00 * c00 + s01 * c01 + s02 * c02
        if det == 0.0:
            raise NumericalError("singular VSCMG mass matrix")
        o0 = (c00 * h0 + (s02 * s21 - s01 * s22) * h1 + (s01 * s12 - s02 * s11) * h2) / det
        o1 = (c01 * h0 + (s00 * s22 - s02 * s20) * h1 + (s02 * s10 - s00 * s12) * h2) / det
        o2 = (c02 * h0 + (s01 * s20 - s00 * s21) * h1 + (s00 * s11 - s01 * s10) * h2) / det
        gr, wr = [], []
        for u, p_g, p_p in zip(geo, pg, pp, strict=True):
            bg0, bg1, bg2, bp0, bp1, bp2, i11, i12, i22 = u[18:27]
            rg = p_g - (bg0 * o0 + bg1 * o1 + bg2 * o2)
            rp = p_p - (bp0 * o0 + bp1 * o1 + bp2 * o2)
            gr.append(i11 * rg + i12 * rp)
            wr.append(i12 * rg + i22 * rp)
        return (o0, o1, o2), gr, wr

    def _forces(
        self, geo: list[tuple[float, ...]], omega: Sequence[float], gr: Sequence[float], wr: Sequence[float]
    ) -> tuple[list[float], list[float]]:
        """``(∂T/∂γ, ∂T/∂φ)`` (:func:`model.body_rates`, :func:`model.internal_forces`)."""
        o0, o1, o2 = omega
        fg, fp = [], []
        for u, ig, g_rate, w_rate in zip(geo, self._ig, gr, wr, strict=True):
            a0, a1, a2, b0, b1, b2, gx, gy, gz = u[:9]
            # ω_G = Cᵀ Ω + γ̇ e_g (gimbal-frame components)
            v0 = a0 * o0 + a1 * o1 + a2 * o2
            v1 = b0 * o0 + b1 * o1 + b2 * o2
            v2 = gx * o0 + gy * o1 + gz * o2 + g_rate
            f_gamma, f_phi = _unit_forces(v0, v1, v2, w_rate, (*ig[:6], *u[9:18]))
            fg.append(f_gamma)
            fp.append(f_phi)
        return fg, fp


_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def _turn_terms(P: list[Array]) -> tuple[tuple[float, ...], tuple[float, ...] | None]:
    """``(P₁, P₂)`` and ``(P₃, P₄)`` of :func:`_turn_basis` as 12 floats each, the second None if zero."""
    odd = _sym6(P[3]) + _sym6(P[4])
    return _sym6(P[1]) + _sym6(P[2]), (odd if any(odd) else None)


def _t9(a: Array) -> Mat9:
    """A (3, 3) array as a row-major 9-tuple of floats."""
    return tuple(np.asarray(a, float).ravel().tolist())  # type: ignore[return-value]


def _sym6(a: Array) -> tuple[float, float, float, float, float, float]:
    """The upper triangle (00, 01, 02, 11, 12, 22) of a (3, 3) array's symmetric part."""
    s = 0.5 * (a + a.T)
    return tuple(float(s[r, c]) for r, c in _UPPER)  # type: ignore[return-value]


def _turn_basis(C0: Array, A: Array) -> list[Array]:
    """``P₀..P₄`` (3, 3) with ``C A Cᵀ = P₀ + P₁ cos 2γ + P₂ sin 2γ + P₃ cos γ + P₄ sin γ`` for the gimbal
    frame ``C = C₀ Rz(γ)`` and a constant gimbal-frame matrix ``A``: ``Rz A Rzᵀ`` keeps the rotation-
    invariant part of A's (s, t) block, turns its symmetric traceless part by 2γ and its (s, t)–g
    couplings by γ."""
    alpha, beta = 0.5 * (A[0, 0] + A[1, 1]), 0.5 * (A[1, 0] - A[0, 1])
    p, q = 0.5 * (A[0, 0] - A[1, 1]), 0.5 * (A[0, 1] + A[1, 0])
    parts = (
        [[alpha, -beta, 0.0], [beta, alpha, 0.0], [0.0, 0.0, A[2, 2]]],
        [[p, q, 0.0], [q, -p, 0.0], [0.0, 0.0, 0.0]],
        [[-q, p, 0.0], [p, q, 0.0], [0.0, 0.0, 0.0]],
        [[0.0, 0.0, A[0, 2]], [0.0, 0.0, A[1, 2]], [A[2, 0], A[2, 1], 0.0]],
        [[0.0, 0.0, -A[1, 2]], [0.0, 0.0, A[0, 2]], [-A[2, 1], A[2, 0], 0.0]],
    )
    return [C0 @ np.array(a, dtype=float) @ C0.T for a in parts]


def _gravity_gradient(
    grav: tuple[float, float, Sequence[float], Sequence[float]],
    t: float,
    R: Sequence[float],
    J: Sequence[float],
) -> Vec3:
    """``R τ`` (inertial) with ``τ = 3 n² r̂ × J r̂`` (:meth:`GravityGradient.torque`)."""
    mean_motion, k, (x0, x1, x2), (q0, q1, q2) = grav
    ang = mean_motion * t
    ca, sa = _cos(ang), _sin(ang)
    e0, e1, e2 = ca * x0 + sa * q0, ca * x1 + sa * q1, ca * x2 + sa * q2
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = R
    b0 = r0 * e0 + r3 * e1 + r6 * e2  # r̂ in the body: Rᵀ e
    b1 = r1 * e0 + r4 * e1 + r7 * e2
    b2 = r2 * e0 + r5 * e1 + r8 * e2
    j0 = J[0] * b0 + J[1] * b1 + J[2] * b2
    j1 = J[3] * b0 + J[4] * b1 + J[5] * b2
    j2 = J[6] * b0 + J[7] * b1 + J[8] * b2
    t0 = k * (b1 * j2 - b2 * j1)
    t1 = k * (b2 * j0 - b0 * j2)
    t2 = k * (b0 * j1 - b1 * j0)
    return (r0 * t0 + r1 * t1 + r2 * t2, r3 * t0 + r4 * t1 + r5 * t2, r6 * t0 + r7 * t1 + r8 * t2)


def _dexpinv(th: Sequence[float], w: Sequence[float]) -> Vec3:
    """``w − ½ Θ×w + (1/12) Θ×(Θ×w)``."""
    t0, t1, t2 = th
    w0, w1, w2 = w
    c0, c1, c2 = t1 * w2 - t2 * w1, t2 * w0 - t0 * w2, t0 * w1 - t1 * w0
    return (
        w0 - 0.5 * c0 + (t1 * c2 - t2 * c1) / 12.0,
        w1 - 0.5 * c1 + (t2 * c0 - t0 * c2) / 12.0,
        w2 - 0.5 * c2 + (t0 * c1 - t1 * c0) / 12.0,
    )
