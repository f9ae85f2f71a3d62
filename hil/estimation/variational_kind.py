"""The ``variational`` estimator kind (the default): the paper's variational estimator as the attitude
filter (:class:`hil.estimation.filter.AttitudeFilter`) with one of its two presets — ``"paper"``, exactly
the paper (its W, m, D, Φ and 1 rad/s body-frame pre-filter, E from the site's full field direction), or
``"tuned"`` (:data:`hil.estimation.filter.TUNED`: a horizontal magnetometer, so only the site's
declination matters). Registered in :mod:`hil.estimation.registry`; pure configuration, no I/O."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hil.estimation.interface import Estimator, Site
from protocol.errors import ConfigError

PRESETS = ("paper", "tuned")
_DESCRIPTIONS = {
    "paper": "preset paper: W, m, D, Φ and the 1 rad/s body-frame pre-filter of the paper",
    "tuned": "preset tuned: strapdown-frame pre-filter, horizontal magnetometer, tuned gains",
}


class VariationalKind:
    """The paper's estimator by preset (see the module docstring)."""

    name = "variational"
    keys = frozenset({"preset"})

    def check(self, settings: Mapping[str, Any], where: str) -> dict[str, Any]:
        """``preset``: ``"paper"`` (default) or ``"tuned"``."""
        preset = settings.get("preset", PRESETS[0])
        if preset not in PRESETS:
            raise ConfigError(f"must be one of {', '.join(PRESETS)}; got {preset!r}", f"{where}.preset")
        return {"preset": preset}

    def build(self, settings: Mapping[str, Any], site: Site) -> Estimator:
        """The attitude filter with the preset's configuration for ``site``: its field (paper) or
        declination (tuned), its initial gyro bias and attitude; a site without a magnetometer runs the
        filter's 6-axis mode."""
        from hil.estimation.filter import AttitudeFilter

        return AttitudeFilter(self.config(settings, site))

    def config(self, settings: Mapping[str, Any], site: Site) -> Any:
        """The :class:`~hil.estimation.filter.FilterConfig` :meth:`build` uses."""
        from hil.estimation.filter import FilterConfig
        from hil.estimation.inertial import directions_from_field

        overrides: dict[str, object] = {"gyro_bias": site.gyro_bias, "init": site.init}
        if not site.magnetometer:
            overrides["magnetometer"] = "none"
        if settings["preset"] == "tuned":
            return FilterConfig.tuned(declination_deg=site.declination_deg, **overrides)
        try:
            directions = directions_from_field(site.field_enu)
        except ConfigError as exc:  # it named "E", a matrix the user never gave
            raise ConfigError(
                f"the site's field {tuple(round(x, 6) for x in site.field_enu)} (ENU) is vertical, parallel "
                "to gravity: the paper's estimator needs two directions that are not (a field of "
                "inclination within ~0.06° of ±90° gives no heading; preset tuned uses the field's "
                "horizontal part only)",
                "estimator variational (preset paper)",
            ) from exc
        return FilterConfig.paper(E=directions, **overrides)

    def describe(self, settings: Mapping[str, Any]) -> str:
        """The preset in one line (``hil replay``'s setup has always said it so)."""
        return _DESCRIPTIONS[settings["preset"]]


VARIATIONAL = VariationalKind()
