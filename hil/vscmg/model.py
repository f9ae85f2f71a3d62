"""The VSCMG spacecraft's mass matrix, momenta, energy and internal generalised forces (docs/dynamics.md).

Everything here is vectorised over a leading batch axis B: gimbal and rotor angles and rates are (B, n),
body rates and momenta (B, 3). Per unit, quantities are worked in gimbal-frame components ``(s, t, g)``
(index 0, 1, 2), where the gimbal structure's inertia is constant and the rotor's depends only on its own
angle φ.

With ``ν = (Ω, γ̇, φ̇)`` the kinetic energy is ``T = ½ νᵀ M(γ, φ) ν`` and its momenta are::

    Π   = J(γ, φ) Ω + Σᵢ (b_γᵢ γ̇ᵢ + b_φᵢ φ̇ᵢ)        body angular momentum about the system's centre of mass
    p_γᵢ = b_γᵢ·Ω + D_i[0,0] γ̇ᵢ + D_i[0,1] φ̇ᵢ            (= gᵢ·(h_Gᵢ + h_Wᵢ))
    p_φᵢ = b_φᵢ·Ω + D_i[1,0] γ̇ᵢ + D_i[1,1] φ̇ᵢ            (= sᵢ·h_Wᵢ)

``J = J₀ + Σ C K̄ Cᵀ`` (the paper's J_T + I_T(t)), ``b_γ = C K̄ e_g``, ``b_φ = C Ī_W^G e_s`` (the columns of
the paper's B(t)), ``D`` the 2×2 gimbal/rotor block (the paper's J_gr). :func:`momenta` computes them body by
body (``Σ I_k ω_k``); :func:`velocities` inverts them through the mass matrix (Schur complement on the
3×3 body block), so the two are independent codes for the same map.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from protocol.errors import ConfigError, NumericalError

from .params import SpacecraftParams, inertia_tensor

Array = NDArray[np.float64]


@dataclass(frozen=True)
class ArrayModel:
    """A :class:`SpacecraftParams` compiled to arrays: ``g, s0, t0`` (n, 3) unit axes (body), ``IG`` (n, 3, 3)
    gimbal-structure inertias in ``(s, t, g)``, ``IW`` (n, 3, 3) rotor inertias in ``(s, w₂, w₃)``, ``J0``
    (3, 3) the constant part of the locked inertia about the system's centre of mass (bus inertia plus every
    body's parallel-axis term, σ included), ``axisymmetric`` True when every rotor is (then Ī_W^G does not
    depend on φ, and ``K = Ī_G + Ī_W`` (n, 3, 3) and ``dinv`` (n, 3), the entries of D⁻¹, are constants).

    Per-run parameters (:meth:`build_batch`, e.g. a Monte Carlo batch whose runs have dispersed inertias,
    misaligned gimbals or rotor offsets): every array gains a leading batch axis B — ``g, s0, t0`` (B, n, 3),
    ``IG, IW, K`` (B, n, 3, 3), ``J0`` (B, 3, 3), ``dinv`` (B, n, 3) — and broadcasts against the states'
    batch axis in every function below; ``params`` is then the first run's."""

    params: SpacecraftParams
    g: Array
    s0: Array
    t0: Array
    IG: Array
    IW: Array
    J0: Array
    axisymmetric: bool
    K: Array
    dinv: Array

    @classmethod
    def build(cls, params: SpacecraftParams) -> ArrayModel:
        units = params.units
        g = np.array([u.gimbal_axis for u in units], dtype=float)
        s0 = np.array([u.spin_axis for u in units], dtype=float)
        g /= np.linalg.norm(g, axis=1, keepdims=True)
        s0 -= np.sum(s0 * g, axis=1, keepdims=True) * g
        s0 /= np.linalg.norm(s0, axis=1, keepdims=True)
        ig = np.array(
            [inertia_tensor(u.gimbal_inertia, f"units[{i}].gimbal_inertia") for i, u in enumerate(units)]
        )
        iw = np.array(
            [inertia_tensor(u.rotor_inertia, f"units[{i}].rotor_inertia") for i, u in enumerate(units)]
        )
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # refused below, in words
            masses, positions = params.point_masses()
            rho = positions - params.center_of_mass_m
            parallel = np.einsum(
                "k,kij->ij",
                masses,
                np.einsum("ki,ki->k", rho, rho)[:, None, None] * np.eye(3)
                - rho[:, :, None] * rho[:, None, :],
            )
            j0 = inertia_tensor(params.bus_inertia, "bus_inertia") + parallel
            axisym = all(u.axisymmetric_rotor for u in units)
            dinv = _block_inverse(ig + iw, iw)
            model = cls(params, g, s0, np.cross(g, s0), ig, iw, j0, axisym, ig + iw, dinv)
            model._check_computable(masses, positions)
        return model

    def _check_computable(self, masses: Array, positions: Array) -> None:
        """Refuse parameters that are each finite and physical but whose model overflows or underflows
        in float64 (ConfigError naming the field), before any state is built: a rotor of 1e160 kg m²
        overflowed its gimbal/rotor block's determinant, D⁻¹ became 0 and the numpy plant stepped a
        400 rad/s rotor to 0 rad/s without a word; a pivot 1e200 m out gave a NaN inertia and NaN states;
        a bus of 1e110 kg m² overflowed the 3×3 determinant the compiled plant solves by, which refused
        what the numpy plant stepped. ``masses`` (k,) kg and ``positions`` (k, 3) m are
        :meth:`SpacecraftParams.point_masses`."""
        second_moments = masses * np.einsum("ki,ki->k", positions, positions)  # kg m², about the reference
        bodies = ["bus_mass_kg, bus_com_m"] + [
            f"units[{i}].{part}_mass_kg, position_m, {part}_offset_m"
            for i in range(self.n)
            for part in ("gimbal", "rotor")
        ]
        for body, moment in zip(bodies, second_moments, strict=True):
            if not np.isfinite(moment):
                raise ConfigError(
                    f"its mass at its position overflows the inertia (m |r|² = {moment} kg m²)",
                    f"SpacecraftParams.{body}",
                )
        if not np.all(np.isfinite(self.J0)):
            raise ConfigError("the masses at their positions overflow the inertia", "SpacecraftParams")
        d11, d12, d22 = self.K[:, 2, 2], self.IW[:, 2, 0], self.IW[:, 0, 0]  # one run's: (n,) each
        det = d11 * d22 - d12 * d12
        for i in range(self.n):
            if not (math.isfinite(det[i]) and det[i] > 0.0 and np.all(np.isfinite(self.dinv[i]))):
                raise ConfigError(
                    f"its gimbal/rotor block (moments {d11[i]:.3g} and {d22[i]:.3g} kg m²) has no usable "
                    "float64 inverse: inertias too large or too small to compute with",
                    f"SpacecraftParams.units[{i}].rotor_inertia, gimbal_inertia",
                )
        zeros = np.zeros((1, self.n))
        for part, inertia in (("bus_inertia", self.J0), ("units", configuration(self, zeros, zeros).J[0])):
            volume = _determinant(inertia)
            if not (math.isfinite(volume) and volume > 0.0):
                raise ConfigError(
                    f"the locked inertia's principal moments ({np.diag(inertia)} kg m² on its diagonal) "
                    "overflow their product, the determinant the plant solves for its rates",
                    f"SpacecraftParams.{part}",
                )

    @classmethod
    def build_batch(cls, runs: Sequence[SpacecraftParams]) -> ArrayModel:
        """One model whose arrays carry each run's own parameters on a leading batch axis (B = len(runs)).
        The runs must have the same number of units (ConfigError otherwise)."""
        models = [cls.build(p) for p in runs]
        if not models:
            raise ConfigError("needs at least one run's parameters", "ArrayModel.build_batch")
        if len({m.n for m in models}) != 1:
            raise ConfigError(
                f"every run needs the same number of units, got {[m.n for m in models]}",
                "ArrayModel.build_batch",
            )
        fields = ("g", "s0", "t0", "IG", "IW", "J0", "K", "dinv")
        stacked = {f: np.stack([getattr(m, f) for m in models]) for f in fields}
        return cls(runs[0], axisymmetric=all(m.axisymmetric for m in models), **stacked)

    @property
    def n(self) -> int:
        return int(self.g.shape[-2])

    @property
    def batch(self) -> int | None:
        """B for per-run parameters (:meth:`build_batch`), None for one set shared by every run."""
        return int(self.J0.shape[0]) if self.J0.ndim == 3 else None


@dataclass(frozen=True)
class Configuration:
    """Geometry at one set of gimbal and rotor angles (batch B): ``C`` (B, n, 3, 3) gimbal frames as columns
    ``(s, t, g)`` in body coordinates, ``IWG`` (B, n, 3, 3) rotor inertias in gimbal-frame components
    ((n, 3, 3) when constant),
    ``J`` (B, 3, 3) the locked inertia J(γ, φ), ``bg, bp`` (B, n, 3) the mass matrix's body–gimbal and
    body–rotor columns ``b_γ = C K̄ e_g``, ``b_φ = C Ī_W^G e_s`` (K̄ = Ī_G + Ī_W^G), and ``dinv`` (B, n, 3)
    the entries (11, 12, 22) of each unit's inverted 2×2 gimbal/rotor block D⁻¹."""

    C: Array
    IWG: Array
    J: Array
    bg: Array
    bp: Array
    dinv: Array


def configuration(m: ArrayModel, gamma: Array, phi: Array) -> Configuration:
    """Frames and inertias at gimbal angles ``gamma`` and rotor angles ``phi`` (B, n) rad."""
    cg, sg = np.cos(gamma)[..., None], np.sin(gamma)[..., None]
    C = np.empty(gamma.shape + (3, 3))
    C[..., 0] = cg * m.s0 + sg * m.t0
    C[..., 1] = cg * m.t0 - sg * m.s0
    C[..., 2] = m.g
    if m.axisymmetric:
        IWG, K, dinv = m.IW, m.K, m.dinv
    else:
        IWG = _rotor_inertia_in_gimbal_frame(m.IW, phi)
        K = m.IG + IWG
        dinv = _block_inverse(K, IWG)
    J = m.J0 + np.sum(C @ K @ np.swapaxes(C, -1, -2), axis=1)
    bg = (C @ K[..., :, 2:3])[..., 0]
    bp = (C @ IWG[..., :, 0:1])[..., 0]
    return Configuration(C, IWG, J, bg, bp, dinv)


def _determinant(inertia: Array) -> float:
    """The product of the principal moments of a symmetric (3, 3) ``inertia`` (kg³ m⁶); inf when it
    overflows or the matrix is not finite."""
    if not np.all(np.isfinite(inertia)):
        return math.inf
    return float(np.prod(np.linalg.eigvalsh(inertia)))


def _block_inverse(K: Array, IWG: Array) -> Array:
    """Entries (11, 12, 22) (..., 3) of ``D⁻¹``, ``D = [[g·K̄g, g·Ī_W s], [s·Ī_W g, s·Ī_W s]]``."""
    d11, d12, d22 = K[..., 2, 2], IWG[..., 2, 0], IWG[..., 0, 0]
    det = d11 * d22 - d12 * d12
    return np.stack([d22 / det, -d12 / det, d11 / det], axis=-1)


def _rotor_inertia_in_gimbal_frame(iw: Array, phi: Array) -> Array:
    """``Rx(φ) Ī_W Rx(φ)ᵀ``, Rx the turn by φ about the spin axis (first component); (B, n, 3, 3).
    ``iw`` is (n, 3, 3) or per run (B, n, 3, 3)."""
    c, s = np.cos(phi), np.sin(phi)
    a, b, cc = iw[..., 0, 0], iw[..., 0, 1], iw[..., 0, 2]
    d, e, f = iw[..., 1, 1], iw[..., 1, 2], iw[..., 2, 2]
    out = np.empty(phi.shape + (3, 3))
    out[..., 0, 0] = a
    out[..., 0, 1] = out[..., 1, 0] = b * c - cc * s
    out[..., 0, 2] = out[..., 2, 0] = b * s + cc * c
    out[..., 1, 1] = c * c * d - 2.0 * c * s * e + s * s * f
    out[..., 1, 2] = out[..., 2, 1] = c * s * (d - f) + (c * c - s * s) * e
    out[..., 2, 2] = s * s * d + 2.0 * c * s * e + c * c * f
    return out


def velocities(
    m: ArrayModel, cfg: Configuration, H: Array, p_gamma: Array, p_phi: Array
) -> tuple[Array, Array, Array]:
    """Solve ``M ν = (Π, p_γ, p_φ)`` for ``(Ω (B, 3), γ̇ (B, n), φ̇ (B, n))``.

    Each unit's 2×2 block is eliminated in closed form, leaving the 3×3 Schur complement
    ``J − Σ Bᵢ Dᵢ⁻¹ Bᵢᵀ`` (the inertia the body feels with every gimbal and rotor free), solved directly."""
    bg, bp = cfg.bg, cfg.bp
    i11, i12, i22 = cfg.dinv[..., 0], cfg.dinv[..., 1], cfg.dinv[..., 2]
    ug = i11[..., None] * bg + i12[..., None] * bp  # rows of B D⁻¹
    up = i12[..., None] * bg + i22[..., None] * bp
    schur = cfg.J - np.einsum("bni,bnj->bij", ug, bg) - np.einsum("bni,bnj->bij", up, bp)
    rhs = H - np.einsum("bni,bn->bi", ug, p_gamma) - np.einsum("bni,bn->bi", up, p_phi)
    try:
        omega = np.linalg.solve(schur, rhs[..., None])[..., 0]
    except np.linalg.LinAlgError as e:
        raise NumericalError(f"singular VSCMG mass matrix: {e}") from e
    rg = p_gamma - np.einsum("bni,bi->bn", bg, omega)
    rp = p_phi - np.einsum("bni,bi->bn", bp, omega)
    return omega, i11 * rg + i12 * rp, i12 * rg + i22 * rp


@dataclass(frozen=True)
class BodyRates:
    """Per-unit angular velocities and momenta in gimbal-frame components (B, n, 3): gimbal structure
    ``wG, hG`` and rotor ``wW, hW`` (rad/s, N m s)."""

    wG: Array
    wW: Array
    hG: Array
    hW: Array


def body_rates(
    m: ArrayModel, cfg: Configuration, omega: Array, gamma_dot: Array, phi_dot: Array
) -> BodyRates:
    """Angular velocities and momenta of every gimbal and rotor: ``ω_G = Cᵀ Ω + γ̇ e_g``,
    ``ω_W = ω_G + φ̇ e_s``, ``h = Ī ω``."""
    wG = np.einsum("bnij,bi->bnj", cfg.C, omega)
    wG[..., 2] += gamma_dot
    wW = wG.copy()
    wW[..., 0] += phi_dot
    hG = (m.IG @ wG[..., None])[..., 0]
    hW = (cfg.IWG @ wW[..., None])[..., 0]
    return BodyRates(wG, wW, hG, hW)


def momenta(m: ArrayModel, cfg: Configuration, omega: Array, rates: BodyRates) -> tuple[Array, Array, Array]:
    """``(Π (B, 3), p_γ (B, n), p_φ (B, n))`` summed body by body: ``Π = J₀ Ω + Σ C (h_G + h_W)``,
    ``p_γ = g·(h_G + h_W)``, ``p_φ = s·h_W``."""
    h = rates.hG + rates.hW
    H = _apply(m.J0, omega) + np.sum((cfg.C @ h[..., None])[..., 0], axis=1)
    return H, h[..., 2], rates.hW[..., 0]


def internal_forces(rates: BodyRates, phi_dot: Array) -> tuple[Array, Array]:
    """``(∂T/∂γ, ∂T/∂φ)`` (B, n) N m at fixed ν — the gyroscopic generalised forces of the gimbal and rotor
    equations ``ṗ = u + ∂T/∂q``::

        ∂T/∂γ = −g·(ω_G × h_G) − g·(ω_W × h_W) + φ̇ t·h_W        ∂T/∂φ = −s·(ω_W × h_W)
    """
    wG, wW, hG, hW = rates.wG, rates.wW, rates.hG, rates.hW
    f_gamma = (
        -(wG[..., 0] * hG[..., 1] - wG[..., 1] * hG[..., 0])
        - (wW[..., 0] * hW[..., 1] - wW[..., 1] * hW[..., 0])
        + phi_dot * hW[..., 1]
    )
    f_phi = -(wW[..., 1] * hW[..., 2] - wW[..., 2] * hW[..., 1])
    return f_gamma, f_phi


def kinetic_energy(m: ArrayModel, omega: Array, rates: BodyRates) -> Array:
    """Rotational kinetic energy (B,) J: ``½ Ωᵀ J₀ Ω + ½ Σ (ω_G·h_G + ω_W·h_W)``."""
    own = 0.5 * np.sum(omega * _apply(m.J0, omega), axis=-1)
    return own + 0.5 * np.sum(rates.wG * rates.hG + rates.wW * rates.hW, axis=(1, 2))


def array_momentum(cfg: Configuration, gamma_dot: Array, phi_dot: Array) -> Array:
    """``Σᵢ (b_γᵢ γ̇ᵢ + b_φᵢ φ̇ᵢ) = Π − J Ω`` (B, 3), body frame (N m s): the momentum the gimbals and rotors
    carry relative to a locked body (the paper's B(t) γ̇ term), which steering manages."""
    return np.einsum("bni,bn->bi", cfg.bg, gamma_dot) + np.einsum("bni,bn->bi", cfg.bp, phi_dot)


def _apply(J: Array, v: Array) -> Array:
    """``J v`` for vectors ``v`` (B, 3) and one matrix (3, 3) or one per run (B, 3, 3)."""
    return (J @ v[..., None])[..., 0]
