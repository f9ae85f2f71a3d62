"""A picture of each fit: bench data against the fitted map (top) and the residuals (bottom).

One unit throughout, the one the fit reports (``FitReport.unit``) and ``hil calibrate`` prints: rad/s for
rotor speeds and gimbal rates, rad for gimbal angles — a bench CSV in rpm or degrees is converted on
reading (the residual axis once showed rpm while the printed residuals were rad/s).
Uses matplotlib's object API on an Agg canvas (no pyplot, no global backend, no display needed).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from protocol.calibration import GimbalAngleMap, GimbalRateMap, RotorSpeedMap
from protocol.errors import ConfigError

from .bench import BenchData
from .fit import Fit
from .textfiles import shown


def plot_path(out: str | os.PathLike[str], unit: int) -> Path:
    """Where a calibration file's unit's fit plot goes by default: beside it, ``<stem>-unit<N>.png``."""
    path = Path(out)
    return path.with_name(f"{path.stem}-unit{unit}.png")


def plot_fits(fits: Sequence[tuple[BenchData, Fit]], path: str | os.PathLike[str], title: str = "") -> Path:
    """Save one column per fit (data and fitted curve; residuals) as an image at ``path`` (PNG, SVG, PDF
    by suffix). Returns the path."""
    import hil.plots  # noqa: F401  (first: it imports matplotlib whatever MPLBACKEND says)

    # isort: split
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.0 * len(fits), 6.5), layout="constrained")
    axes = fig.subplots(2, len(fits), squeeze=False, height_ratios=(3, 1), sharex="col")
    for col, (data, fit) in enumerate(fits):
        top, bottom = axes[0][col], axes[1][col]
        grid = np.linspace(float(data.pulse_us.min()), float(data.pulse_us.max()), 400)
        m = fit.map
        r = fit.report
        if isinstance(m, RotorSpeedMap):
            points = top.scatter(data.pulse_us, data.value, c=data.battery_v, s=8, cmap="viridis")
            fig.colorbar(points, ax=top, label="battery (V)")
            v_lo, v_hi = float(np.nanmin(data.battery_v)), float(np.nanmax(data.battery_v))
            for v in sorted({v_lo, v_hi}):
                top.plot(grid, [m.speed(p, v).value for p in grid], lw=1.2, label=f"fit at {v:.2f} V")
            top.set_ylabel(f"no-load speed ({r.unit})")
            top.axvline(m.esc.start_us, color="grey", lw=0.8, ls=":", label="deadband end")
        else:
            top.scatter(data.pulse_us, data.value, s=8, color="tab:blue", label="bench data")
            if isinstance(m, GimbalRateMap):
                top.plot(grid, [m.rate(p).value for p in grid], color="tab:red", lw=1.2, label="fit")
                top.axvspan(*m.dead_zone_us, color="grey", alpha=0.25, label="dead zone")
                top.set_ylabel(f"gimbal rate ({r.unit})")
            elif isinstance(m, GimbalAngleMap):
                top.plot(grid, [m.angle(p).value for p in grid], color="tab:red", lw=1.2, label="fit")
                top.set_ylabel(f"gimbal angle ({r.unit})")
        top.set_title(
            f"{data.kind.value}: {shown(Path(data.path).name)}\nrms {r.rms:.3g} {r.unit}, max {r.max_abs:.3g}"
        )
        top.legend(fontsize="small")
        top.grid(alpha=0.3)
        bottom.scatter(data.pulse_us, r.residuals, s=6, color="tab:gray")
        bottom.axhline(0.0, color="black", lw=0.8)
        bottom.set_xlabel("pulse (µs)")
        bottom.set_ylabel(f"residual ({r.unit})")
        bottom.grid(alpha=0.3)
    if title:
        fig.suptitle(shown(title))
    out = Path(path)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=110)
    except (OSError, ValueError) as exc:  # ValueError: a suffix matplotlib has no writer for
        raise ConfigError(f"cannot save the plot: {exc}", str(path)) from exc
    return out
