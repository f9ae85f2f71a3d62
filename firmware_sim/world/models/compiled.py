"""The compiled plant: :class:`Plant`'s RKMK4 step for one run, as one compiled kernel (:mod:`.kernels`)
on a flat float64 state, many steps per call.

:class:`Plant` (numpy, batched) is the reference; this is what the emulator's world steps. A step costs a
few microseconds inside a compiled loop: no Python objects per step, nothing allocated. The state is one
flat array (:func:`.kernels.state_size` floats: t, R, the integrated variables as :meth:`Plant.step`
stacks them, then Ω, γ̇, φ̇); :meth:`CompiledPlant.pack` and :meth:`CompiledPlant.unpack` convert to and
from :class:`PlantState` (batch 1) exactly, and the ``*_of`` helpers read views of it.

Torques: None, a held ``(gimbal, rotor)`` pair, a :class:`.drives.Drive`, or anything with a ``drive()``
method returning one (:class:`.servos.ServoModel`): the drive law runs inside the
compiled stages. A Python torque law cannot (the compiled loop does not call back into Python): step
those on :class:`Plant`.

``NUMBA_DISABLE_JIT=1`` runs the same kernels as plain Python (slowly; for debugging).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from protocol.errors import ConfigError, NumericalError

from . import kernels as k
from .drives import Drive
from .plant import Plant, PlantState, Torques, check_time_reached

Array = NDArray[np.float64]

_NO_PATH = np.zeros((0, k.PATH_WIDTH))


class CompiledPlant:
    """:meth:`Plant.step` compiled, for one run. Built from a plant (its :class:`ArrayModel` and gravity):
    ``plant.model`` must describe one spacecraft (shared parameters, or per-run parameters of a batch of
    1)."""

    def __init__(self, plant: Plant) -> None:
        m = plant.model
        if m.batch not in (None, 1):
            raise ConfigError(f"needs one run's parameters, the plant has {m.batch}", "CompiledPlant")

        def one(a: Array) -> Array:
            return a[0] if m.batch is not None else a

        self.plant = plant
        self.n = n = m.n
        model = np.zeros(k.model_size(n))
        model[0], model[1] = n, float(m.axisymmetric)
        gr = plant.gravity
        if gr is not None:
            r0 = np.asarray(gr.radial_at_epoch, float)
            model[2:5] = 1.0, gr.mean_motion, 3.0 * gr.mean_motion**2
            model[5:8] = r0
            model[8:11] = np.cross(np.asarray(gr.orbit_normal, float), r0)
        model[11:20] = one(m.J0).ravel()
        g, s0, t0, IG, IW, dinv = (one(a) for a in (m.g, m.s0, m.t0, m.IG, m.IW, m.dinv))
        for i in range(n):
            u = k.M_HEADER + k.M_UNIT * i
            model[u : u + k.M_UNIT] = np.concatenate(
                [s0[i], t0[i], g[i], IG[i].ravel(), IW[i].ravel(), dinv[i]]
            )
        self.model = model
        self.size = k.state_size(n)
        self._work = np.zeros(k.work_size(n))
        nx = 3 + 4 * n
        self._x = slice(10, 10 + nx)
        self._omega = slice(10 + nx, 13 + nx)
        self._gimbal_rate = slice(13 + nx, 13 + nx + n)
        self._rotor_rate = slice(13 + nx + n, 13 + nx + 2 * n)
        self.path_columns = np.r_[0:10, 10 + nx : 13 + nx]
        """The columns of a whole-state path (:meth:`advance`) that make a path of t, R, Ω rows."""

    # ------------------------------------------------------------------ state
    def pack(self, s: PlantState, index: int = 0) -> Array:
        """Run ``index`` of ``s`` as a flat state (a new array)."""
        if s.gimbal_angle.shape[-1] != self.n:
            raise ConfigError(
                f"the state has {s.gimbal_angle.shape[-1]} units, not {self.n}", "CompiledPlant"
            )
        i = index
        return np.concatenate(
            [
                [s.t],
                s.R[i].ravel(),
                s.momentum[i],
                s.gimbal_angle[i],
                s.rotor_angle[i],
                s.gimbal_momentum[i],
                s.rotor_momentum[i],
                s.omega[i],
                s.gimbal_rate[i],
                s.rotor_rate[i],
            ]
        ).astype(float)

    def unpack(self, state: Array) -> PlantState:
        """A flat state as a :class:`PlantState` of batch 1 (copies)."""
        n, x = self.n, state[self._x]
        return PlantState(
            float(state[0]),
            state[1:10].reshape(1, 3, 3).copy(),
            x[None, 0:3].copy(),
            x[None, 3 : 3 + n].copy(),
            x[None, 3 + n : 3 + 2 * n].copy(),
            x[None, 3 + 2 * n : 3 + 3 * n].copy(),
            x[None, 3 + 3 * n :].copy(),
            state[None, self._omega].copy(),
            state[None, self._gimbal_rate].copy(),
            state[None, self._rotor_rate].copy(),
        )

    def R_of(self, state: Array) -> Array:
        """The attitude (3, 3), a view."""
        return state[1:10].reshape(3, 3)

    def omega_of(self, state: Array) -> Array:
        """The body rate Ω (3,) rad/s, a view."""
        return state[self._omega]

    def gimbal_angle_of(self, state: Array) -> Array:
        return state[10 + 3 : 10 + 3 + self.n]

    def gimbal_rate_of(self, state: Array) -> Array:
        return state[self._gimbal_rate]

    def rotor_rate_of(self, state: Array) -> Array:
        """Rotor speeds relative to their gimbals (n,) rad/s, a view."""
        return state[self._rotor_rate]

    # ------------------------------------------------------------------ stepping
    def drive(self, torques: Torques | Drive | Any) -> Drive:
        """``torques`` as the compiled plant's :class:`Drive` (ConfigError for a Python torque law)."""
        if torques is None:
            return Drive.none()
        packed = getattr(torques, "drive", None)  # ServoModel.drive
        if isinstance(torques, Drive):
            d = torques
        elif callable(packed):
            d = packed()
        elif callable(torques):
            raise ConfigError(
                "the compiled plant evaluates its drive law, not a Python torque law: step it on Plant",
                "CompiledPlant.torques",
            )
        else:
            d = Drive.constant(torques[0], torques[1], self.n)
        if d.units() not in (None, self.n):
            raise ConfigError(
                f"a drive for {d.units()} units, the plant has {self.n}", "CompiledPlant.torques"
            )
        return d

    def advance(
        self,
        state: Array,
        dt: float,
        steps: int,
        torques: Torques | Drive | Any = None,
        path: Array | None = None,
    ) -> None:
        """``steps`` steps of ``dt`` seconds on ``state`` in place (RKMK4, as :meth:`Plant.step`). With
        ``path`` ((steps + 1, 13): t, R, Ω per row; or (steps + 1, :attr:`size`): whole states) the start and
        every state reached are recorded. Raises
        NumericalError as the reference does (the state is then the last good one)."""
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ConfigError(f"must be a positive step, got {dt!r}", "CompiledPlant.step.dt")
        if state.shape != (self.size,) or state.dtype != np.float64:
            raise ConfigError(f"needs a float64 state of {self.size}, got {state.shape}", "CompiledPlant")
        check_time_reached(float(state[0]), dt, steps, "CompiledPlant.advance")
        d = self.drive(torques)
        if path is None:
            path = _NO_PATH
        elif path.shape not in ((steps + 1, k.PATH_WIDTH), (steps + 1, self.size)):
            raise ConfigError(
                f"needs a path of ({steps + 1}, {k.PATH_WIDTH}) or ({steps + 1}, {self.size})",
                "CompiledPlant.advance.path",
            )
        try:
            status, _ = k.advance(self.model, state, float(dt), int(steps), d.mode, d.data, path, self._work)
        except (ValueError, OverflowError, ZeroDivisionError) as e:
            # the kernels run as plain Python (NUMBA_DISABLE_JIT=1): math raises where compiled code makes
            # inf or NaN, and the state is then the last good one as well
            t = float(state[0])
            raise NumericalError(f"the plant state diverged after t = {t:.6g} s (step {dt:g} s)") from e
        if status != k.OK:
            self._raise(status, dt)

    def _raise(self, status: int, dt: float) -> None:
        w, n = self._work, self.n
        t = float(w[0])
        if status == k.BAD_TORQUE:
            gimbal, rotor = w[1 : 1 + n], w[1 + n : 1 + 2 * n]
            raise NumericalError(f"non-finite motor torque at t = {t:.6g} s: gimbal {gimbal}, rotor {rotor}")
        if status == k.SINGULAR:
            raise NumericalError(f"singular VSCMG mass matrix at t = {t:.6g} s")
        raise NumericalError(f"the plant state diverged at t = {t:.6g} s (step {dt:g} s too long?)")

    def step(self, state: Array, dt: float, torques: Torques | Drive | Any = None) -> Array:
        """One step from ``state`` (left as it is) to a new flat state."""
        out = state.copy()
        self.advance(out, dt, 1, torques)
        return out

    def step_state(self, s: PlantState, dt: float, torques: Torques | Drive | Any = None) -> PlantState:
        """:meth:`Plant.step` for a state of batch 1."""
        if s.batch != 1:
            raise ConfigError(f"steps one run, the state has {s.batch}", "CompiledPlant.step_state")
        return self.unpack(self.step(self.pack(s), dt, torques))

    def run(
        self,
        s: PlantState,
        dt: float,
        n_steps: int,
        torques: Torques | Drive | Any = None,
        observe: Callable[[PlantState], None] | None = None,
    ) -> PlantState:
        """:meth:`Plant.run` for a state of batch 1 (one compiled call, unless ``observe`` wants every
        state)."""
        if s.batch != 1:
            raise ConfigError(f"steps one run, the state has {s.batch}", "CompiledPlant.run")
        state = self.pack(s)
        if observe is None:
            self.advance(state, dt, n_steps, torques)
        else:
            for _ in range(n_steps):
                self.advance(state, dt, 1, torques)
                observe(self.unpack(state))
        return self.unpack(state)
