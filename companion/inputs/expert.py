"""A scripted expert pilot and the rule by which a watching expert intervenes.

The expert flies the landing the way a person watching the downward camera would: steer the
pad towards the centre of the image, descend while it is roughly centred, slow down when it
looks big, and keep landing if it fills the view at the very end. It sees only the screen
(pad pixel position and size) and what a pilot feels (attitude, ground speed, climb rate);
never ground truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from companion.commands import JoystickCommand
from companion.config import PilotConfig
from companion.inputs.base import HumanCommand, HumanInput
from companion.inputs.pad_view import PadEstimate, estimate_pad, heading_velocity

if TYPE_CHECKING:
    from companion.observation import Observation


def view_of(obs: Observation, cfg: PilotConfig) -> PadEstimate | None:
    """The pad as the pilot judges it from this observation; None when it is not on screen."""
    if obs.pad is None:
        return None
    return estimate_pad(
        obs.pad,
        (float(obs.image_size_px[0]), float(obs.image_size_px[1])),
        tuple(obs.attitude_rad),  # type: ignore[arg-type]
        cfg.pad_radius_m,
        math.radians(cfg.camera_hfov_deg),
    )


def _stick(value: float, limit: float = 1.0) -> float:
    return float(np.clip(value, -limit, limit))


class ScriptedExpert(HumanInput):
    """Centre over the pad, descend, slow down near touchdown, land. Always holds the override.

    Gains are in stick units (per metre of offset, per m/s of speed), as a person would learn
    them for a given vehicle. Memory: a trim that grows while an offset lasts (as a pilot
    leans on the stick against a drift), and the last height at which the pad was seen, so
    that losing the pad right above it means "keep landing" rather than "search".
    """

    def __init__(self, cfg: PilotConfig) -> None:
        self.cfg = cfg
        self.reset()

    def reset(self) -> None:
        self._last_height_m: float | None = None
        self._last_seen_ms: int | None = None
        self._last_command = JoystickCommand.neutral()
        self._trim = np.zeros(2)  # forward, right; stick units

    def read(self, obs: Observation) -> HumanCommand:
        return HumanCommand(self.command(obs), override_held=True)

    def command(self, obs: Observation) -> JoystickCommand:
        """The expert's sticks for this observation (also used when only watching)."""
        yaw_rad = float(obs.attitude_rad[2])
        vel = heading_velocity(tuple(obs.velocity_ned_m_s), yaw_rad)  # type: ignore[arg-type]
        now_ms = int(obs.time_boot_ms)
        view = view_of(obs, self.cfg)
        if view is None:
            return self._pad_lost(vel, now_ms)
        self._update_trim(view, now_ms)
        self._last_height_m, self._last_seen_ms = view.height_m, now_ms
        pitch = self._steer(view.forward_m, vel[0], self._trim[0])
        roll = self._steer(view.right_m, vel[1], self._trim[1])
        self._last_command = JoystickCommand(roll, pitch, 0.0, -self._descent(view))
        return self._last_command

    def _update_trim(self, view: PadEstimate, now_ms: int) -> None:
        last = self._last_seen_ms
        dt_s = 0.0 if last is None else min(max(0.0, (now_ms - last) / 1e3), 1.0)
        offset = np.array([view.forward_m, view.right_m])
        limit = self.cfg.xy_trim_max
        self._trim = np.clip(self._trim + self.cfg.xy_trim_per_m_s * offset * dt_s, -limit, limit)

    def _steer(self, offset_m: float, speed_m_s: float, trim: float) -> float:
        c = self.cfg
        demand = c.xy_gain_per_m * offset_m - c.xy_damping_per_m_s * speed_m_s + trim
        return _stick(demand, c.xy_stick_max)

    def _descent(self, view: PadEstimate) -> float:
        """Descent stick: fast when high, slow near the pad, less while off-centre."""
        c = self.cfg
        blend = np.clip((view.height_m - c.slow_height_m) / c.slow_height_m, 0.0, 1.0)
        rate = c.descent_stick_slow + (c.descent_stick_fast - c.descent_stick_slow) * blend
        allowed_m = max(c.centre_tolerance_m, c.descent_cone * view.height_m)
        centred = np.clip(2.0 - view.offset_m / allowed_m, 0.0, 1.0)
        return float(rate * centred)

    def _pad_lost(self, vel: np.ndarray, now_ms: int) -> JoystickCommand:
        """A blink: carry on. Longer: brake; keep landing if the pad was last seen just below,
        else climb to find it."""
        c = self.cfg
        seen = self._last_seen_ms
        if seen is not None and now_ms - seen < c.lost_hold_s * 1000.0:
            return self._last_command
        pitch = self._steer(0.0, vel[0], self._trim[0])
        roll = self._steer(0.0, vel[1], self._trim[1])
        landing = self._last_height_m is not None and self._last_height_m <= c.commit_height_m
        throttle = -c.descent_stick_slow if landing else c.search_climb_stick
        return JoystickCommand(roll=roll, pitch=pitch, yaw=0.0, throttle=throttle)


@dataclass(frozen=True)
class RuleState:
    """What the intervention rule concluded at one tick (for logs and tests)."""

    holding: bool
    reason: str | None
    """Why the expert is (still) holding, or None when the agent flies."""


class InterventionRule:
    """When a watching expert takes over, and when they let go.

    Take over at once when any of these is seen: the pad is lost (unless it vanished right
    below, at touchdown); the pad drifts towards the image edge (``takeover_edge_fraction``);
    the vehicle descends faster than ``takeover_descent_m_s``; or it is off-centre by more than
    ``takeover_off_centre_m`` below ``takeover_low_height_m``. Let go once the vehicle has
    been back on track - pad within ``release_edge_fraction``, descent rate fine, and (when
    low) within ``release_off_centre_m`` - for ``release_hold_s`` of observation time. The
    release thresholds are tighter than the take-over ones, so the rule does not chatter.
    """

    def __init__(self, cfg: PilotConfig) -> None:
        self.cfg = cfg
        self.reset()

    def reset(self) -> None:
        self._holding = False
        self._on_track_since_ms: int | None = None
        self._last_height_m: float | None = None
        self.takeovers = 0

    def update(self, obs: Observation) -> RuleState:
        """Advance the rule by one observation."""
        view = view_of(obs, self.cfg)
        danger = self._danger(obs, view)
        if view is not None:
            self._last_height_m = view.height_m
        if not self._holding:
            if danger is not None:
                self._holding, self._on_track_since_ms = True, None
                self.takeovers += 1
            return RuleState(self._holding, danger)
        if danger is not None or not self._on_track(obs, view):
            self._on_track_since_ms = None
            return RuleState(True, danger or "not yet back on track")
        now_ms = int(obs.time_boot_ms)
        if self._on_track_since_ms is None:
            self._on_track_since_ms = now_ms
        if now_ms - self._on_track_since_ms >= self.cfg.release_hold_s * 1000.0:
            self._holding = False
            return RuleState(False, None)
        return RuleState(True, "holding until steady")

    def _danger(self, obs: Observation, view: PadEstimate | None) -> str | None:
        c = self.cfg
        if view is None:
            at_touchdown = (
                self._last_height_m is not None and self._last_height_m <= c.commit_height_m
            )
            return None if at_touchdown else "pad lost"
        if view.edge_fraction > c.takeover_edge_fraction:
            return "pad near the image edge"
        if float(obs.velocity_ned_m_s[2]) > c.takeover_descent_m_s:
            return "descending too fast"
        if view.height_m < c.takeover_low_height_m and view.offset_m > c.takeover_off_centre_m:
            return "off-centre at low height"
        return None

    def _on_track(self, obs: Observation, view: PadEstimate | None) -> bool:
        c = self.cfg
        if view is None:
            return False
        low = view.height_m < c.takeover_low_height_m
        return (
            view.edge_fraction <= c.release_edge_fraction
            and float(obs.velocity_ned_m_s[2]) <= c.takeover_descent_m_s
            and (not low or view.offset_m <= c.release_off_centre_m)
        )


class InterveningExpert(HumanInput):
    """A synthetic operator for interventions: the expert's sticks, override by the rule."""

    def __init__(self, cfg: PilotConfig) -> None:
        self.expert = ScriptedExpert(cfg)
        self.rule = InterventionRule(cfg)
        self.last_state = RuleState(False, None)

    def reset(self) -> None:
        self.expert.reset()
        self.rule.reset()
        self.last_state = RuleState(False, None)

    def read(self, obs: Observation) -> HumanCommand:
        cmd = self.expert.command(obs)  # every tick, so the expert's memory stays current
        self.last_state = self.rule.update(obs)
        return HumanCommand(cmd, override_held=self.last_state.holding)
