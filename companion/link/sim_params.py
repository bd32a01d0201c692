"""A real autopilot's own simulator disturbed as our SITL is: ``[sitl.disturbance]`` set through
the SITL parameters of ArduCopter and PX4 SIH, over MAVLink, at each episode's start.

What maps to what (docs/link.md, "Disturbances on the real autopilots"):

- **steady wind** (our ``wind_speed_max_m_s`` x level, direction drawn per episode from its
  seed): ArduPilot ``SIM_WIND_SPD`` (m/s) and ``SIM_WIND_DIR`` (degrees true the wind comes
  *from*), with ``SIM_WIND_T = 1`` (the same wind at every height, as ours; ArduPilot's default
  weakens it below ``SIM_WIND_T_ALT``, 60 m). PX4 SIH has no wind: not applied, said in the record.
- **turbulence** (our MIL-F-8785C ``turbulence_w20_max_m_s`` x level): ArduPilot ``SIM_WIND_TURB``,
  the standard deviation of its low-pass random wind (m/s, horizontal and vertical alike), set to
  MIL-F-8785C's horizontal intensity at the start height, sigma_u = 0.1 W20 / (0.177 + 0.000823 h
  [ft])^0.4. The two differ in spectrum and in direction (ArduPilot's turns at random): a level,
  not a replica. PX4 SIH: none.
- **the ground vehicle driving** (our ``vehicle_speed_max_m_s`` x level, direction drawn per
  episode): not the autopilot's, the rendered camera's: its pad drives at ``[sitl.world]``'s
  velocity plus this from each episode's hand-over (:meth:`AutopilotSim.pad_drift_for`).
- **a heavier or draggier vehicle** than the one a policy was trained on (no equivalent in our
  SITL's level): PX4 SIH ``SIH_MASS`` and ``SIH_KDV`` (translational drag), each the value the
  autopilot had when first asked, times ``[companion.session] sih_mass_scale`` / ``sih_drag_scale``.

Every value is confirmed by the vehicle's PARAM_VALUE echo; what was found before is put back by
:meth:`AutopilotSim.restore` at the end of the run (ArduPilot keeps parameters in its SITL's
eeprom.bin across restarts). Pure mapping here; :class:`AutopilotSim` does the link calls.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

from companion.errors import CommandRejected, ConfigError
from companion.link.base import VehicleLink

log = logging.getLogger(__name__)
PARAM_TOLERANCE = 1e-3
FT_PER_M = 1.0 / 0.3048
# How long an episode start waits for a parameter's echo (PARAM_SET or PARAM_REQUEST_READ sent again
# every command_timeout_s meanwhile). A command's 4 s was once too short: PX4 SIH at 4x beside a
# full test run left SIH_MASS unechoed for all four tries (bench/results/ci-fresh-2026-12-07-33-failed.txt),
# and the episode was lost. Waiting at an episode's start costs nothing when the answer comes.
PARAM_BUDGET_S = 15.0
WIND_TYPE_NO_LIMIT = 1  # ArduPilot SIM_WIND_T: no reduction of the wind near the ground
ARDUPILOT, PX4 = "ARDUPILOTMEGA", "PX4"  # the HEARTBEAT's autopilot, as the snapshot names it


@dataclass(frozen=True)
class SimEpisode:
    """One episode's disturbance as our SITL draws it (sitl/disturbance.py): where the wind blows
    to, the turbulence's MIL-F-8785C wind speed at 20 ft, and the ground vehicle's drive added
    to ``[sitl.world]``'s (the rendered camera's moving pad: companion/vision/rendered.py)."""

    wind_ne_m_s: tuple[float, float] = (0.0, 0.0)
    turbulence_w20_m_s: float = 0.0
    pad_drift_ne_m_s: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class Param:
    """One SITL parameter and the value to set it to."""

    name: str
    value: float


def milspec_sigma_u(w20_m_s: float, height_m: float) -> float:
    """MIL-F-8785C low-altitude horizontal turbulence intensity (m/s) at ``height_m`` (at least
    10 ft, as the standard's formula is used): sigma_w = 0.1 W20, sigma_u = sigma_w / (0.177 +
    0.000823 h)^0.4 with h in feet."""
    if w20_m_s <= 0:
        return 0.0
    h_ft = max(height_m * FT_PER_M, 10.0)
    return 0.1 * w20_m_s / (0.177 + 0.000823 * h_ft) ** 0.4


def wind_from_deg(wind_ne_m_s: tuple[float, float]) -> float:
    """Where the wind comes from, degrees true in [0, 360): the opposite of where it blows to."""
    north, east = wind_ne_m_s
    return math.degrees(math.atan2(-east, -north)) % 360.0


def ardupilot_weather(weather: SimEpisode, height_m: float) -> tuple[Param, ...]:
    """ArduPilot's SIM_WIND_* for one episode's air (module docstring)."""
    return (Param("SIM_WIND_T", WIND_TYPE_NO_LIMIT),
            Param("SIM_WIND_SPD", round(math.hypot(*weather.wind_ne_m_s), 4)),
            Param("SIM_WIND_DIR", round(wind_from_deg(weather.wind_ne_m_s), 3)),
            Param("SIM_WIND_TURB", round(milspec_sigma_u(weather.turbulence_w20_m_s, height_m), 4)))


def px4_sih_body(found: dict[str, float], mass_scale: float, drag_scale: float) -> tuple[Param, ...]:
    """PX4 SIH's SIH_MASS and SIH_KDV, scaled from the values ``found`` (nothing for a scale of 1)."""
    out = []
    for name, scale in (("SIH_MASS", mass_scale), ("SIH_KDV", drag_scale)):
        if scale != 1.0:
            out.append(Param(name, round(found[name] * scale, 6)))
    return tuple(out)


class AutopilotSim:
    """Sets a real autopilot's SITL parameters per episode (module docstring).

    ``episode_for(seed)``: the episode's air (the wiring draws it with our SITL's own rule, so
    the same seed gives the same wind on every vehicle); ``height_m``: the start height above
    the ground, where turbulence is sized."""

    def __init__(self, episode_for: Callable[[int], SimEpisode], height_m: float,
                 mass_scale: float = 1.0, drag_scale: float = 1.0, disturb: bool = True) -> None:
        if not (mass_scale > 0 and drag_scale > 0):
            raise ConfigError(f"sih_mass_scale and sih_drag_scale must be positive (got {mass_scale:g}, {drag_scale:g})")
        self.episode_for, self.height_m = episode_for, height_m
        self.mass_scale, self.drag_scale, self.disturb = mass_scale, drag_scale, disturb
        self.found: dict[str, float] = {}  # each parameter as the vehicle had it before the first set

    def params_for(self, autopilot: str, seed: int) -> tuple[tuple[Param, ...], list[str]]:
        """What to set on this autopilot for this episode, and notes on what cannot be."""
        weather = self.episode_for(seed)
        calm = weather.wind_ne_m_s == (0.0, 0.0) and weather.turbulence_w20_m_s == 0.0
        if autopilot == ARDUPILOT:
            if self.mass_scale != 1.0 or self.drag_scale != 1.0:
                raise ConfigError("sih_mass_scale / sih_drag_scale set a PX4 SIH vehicle's SIH_MASS / SIH_KDV; "
                                  "this vehicle is ArduPilot: leave them at 1")
            return (ardupilot_weather(weather, self.height_m) if self.disturb else ()), []
        if autopilot == PX4:
            notes = [] if calm or not self.disturb else [
                f"sim: PX4 SIH has no wind: wind {math.hypot(*weather.wind_ne_m_s):.2f} m/s and turbulence "
                f"(W20 {weather.turbulence_w20_m_s:.2f} m/s) not applied"]
            return px4_sih_body(self.found, self.mass_scale, self.drag_scale), notes
        raise ConfigError(f"autopilot_sim_disturbance: {autopilot!r} is not an autopilot SITL this knows "
                          "(ArduCopter SITL or PX4 SIH); turn it off for a real vehicle")

    def pad_drift_for(self, seed: int) -> tuple[float, float]:
        """The ground vehicle's drive this episode (north, east; m/s), added to the rendered world's."""
        return self.episode_for(seed).pad_drift_ne_m_s if self.disturb else (0.0, 0.0)

    def prepare_episode(self, link: VehicleLink, autopilot: str, seed: int) -> list[str]:
        """Set this episode's parameters (each echo checked): notes for the episode record."""
        if autopilot == PX4 and not self.found:
            self._remember(link, ("SIH_MASS", "SIH_KDV"))
        params, notes = self.params_for(autopilot, seed)
        self._remember(link, tuple(p.name for p in params if p.name not in self.found))
        for p in params:
            self._set(link, p.name, p.value)
        if params:
            notes.insert(0, "sim: " + ", ".join(f"{p.name}={p.value:g}" for p in params))
        return notes

    def restore(self, link: VehicleLink) -> None:
        """Put back what was found (best effort: logged, never raised, as the run ends)."""
        for name, value in self.found.items():
            try:
                self._set(link, name, value)
            except Exception as exc:  # noqa: BLE001 - the run is ending; say it and go on
                log.warning("could not put %s back to %g: %s", name, value, exc)

    def _remember(self, link: VehicleLink, names: tuple[str, ...]) -> None:
        for name in names:
            value = link.read_param(name, PARAM_BUDGET_S)
            if value is None:
                raise CommandRejected(f"PARAM_REQUEST_READ {name}", "NO_ANSWER",
                                      "the vehicle does not have it: is this its SITL (ArduCopter SITL, PX4 SIH)?")
            self.found[name] = value

    @staticmethod
    def _set(link: VehicleLink, name: str, value: float) -> None:
        echoed = link.set_param(name, value, PARAM_BUDGET_S)
        if echoed is None or not math.isclose(echoed, value, rel_tol=1e-5, abs_tol=PARAM_TOLERANCE):
            raise CommandRejected(f"PARAM_SET {name}={value:g}", "NOT_CONFIRMED",
                                  f"the vehicle echoed {echoed}; is this its SITL?")
