"""A scripted expert pilot and the rule by which a watching expert intervenes.

The expert flies the landing the way a person watching the downward camera would: steer the
pad towards the centre of the image, descend while it is roughly centred, slow down when it
looks big, and keep landing if it fills the view at the very end. It sees only the screen
(pad pixel position and size) and what a pilot feels (attitude, ground speed, climb rate);
never ground truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from companion.config import PilotConfig
from companion.inputs.base import HumanCommand, HumanInput
from companion.inputs.pad_motion import PadMotion, heading_frame, pad_ground_position
from companion.inputs.pad_view import PadEstimate, estimate_pad, heading_velocity
from companion.inputs.picture_drift import PictureDrift
from companion.msg.command import JoystickCommand

if TYPE_CHECKING:
    from companion.msg.observation import Observation


PARTIAL_HEIGHT_MARGIN_M = 0.15  # set_down_by_picture: a pad seen from this much higher is stray


def view_of(obs: Observation, cfg: PilotConfig) -> PadEstimate | None:
    """The pad as the pilot judges it from this observation; None when it is not on screen."""
    if obs.pad is None:
        return None
    return estimate_pad(
        obs.pad,
        (float(obs.image_size_px[0]), float(obs.image_size_px[1])),
        obs.attitude_rad,
        cfg.pad_radius_m,
        math.radians(cfg.camera_hfov_deg),
    )


def _stick(value: float, limit: float = 1.0) -> float:
    return float(np.clip(value, -limit, limit))


class TouchdownCommit:
    """Whether the pilot has committed to touchdown, and where they believe the pad is then.

    Close above the pad it fills the view: the detector sees only its rim or stray blobs
    (reported as partial), and the estimates jump. A person then ignores such glimpses and
    sets the vehicle down where they last saw the pad whole, judging their own drift from
    the vehicle's motion (its local position); a whole pad in view is still believed.
    Committed once the pad is seen centred (within ``commit_off_centre_m``) at or below
    ``commit_height_m``; until reset.

    ``by_picture`` (``set_down_by_picture``): a partial pad whose centre is in the picture (the
    detector's centre from the white dot or the rim, edge fraction <= 1) is believed too, as a
    person keeps watching the pad's centre while setting down; and a pad, partial or whole,
    whose size would put the camera more than ``PARTIAL_HEIGHT_MARGIN_M`` above where the pad
    last believed was seen from is not (setting down, the camera only comes lower: such a blob
    is stray; a whole one 10 px across in a corner, 0.1 m above the pad, was seen too; on real ArduCopter one
    seen 0.07 m above the pad, as if from 0.75 m, moved the remembered pad 0.5 m; a gate on the
    jump of the pad's position instead also dropped the real pad where the estimate drifted, PX4
    SIH 1 of 9; results/real-autopilots/RENDER.md). Where the vehicle's position
    estimate drifts from the truth the camera shows (PX4 SIH: its velocity estimate 0.2-0.3 m/s
    off in flight, results/real-autopilots/RENDER.md), the remembered position moves with the
    estimate and the set-down lands off the pad; the picture does not.
    """

    def __init__(self, cfg: PilotConfig, by_picture: bool = False) -> None:
        self.height_m = cfg.commit_height_m
        self.off_centre_m = cfg.commit_off_centre_m
        self.by_picture = by_picture
        self.reset()

    def reset(self) -> None:
        self.committed = False
        self._pad_ne_m = np.zeros(2)
        self.seen_ms = 0  # vehicle time of the pad's position last believed
        self._view_height_m = self.height_m  # the height the pad last believed was seen from

    def update(self, view: PadEstimate | None, obs: Observation) -> PadEstimate | None:
        """The view to act on: None for a partial pad once committed."""
        if view is None:
            return None
        if not self.committed:
            if view.height_m <= self.height_m and view.offset_m <= self.off_centre_m:
                self.committed = True
                self._pad_ne_m = self._pad_position(view, obs)
                self.seen_ms = int(obs.time_boot_ms)
                self._view_height_m = view.height_m
            return view
        if view.partial and not (self.by_picture and view.edge_fraction <= 1.0):
            return None
        if self.by_picture and view.height_m > self._view_height_m + PARTIAL_HEIGHT_MARGIN_M:
            return None  # a stray blob, not the pad: setting down, the camera only comes lower
        self._pad_ne_m = self._pad_position(view, obs)
        self.seen_ms = int(obs.time_boot_ms)
        self._view_height_m = view.height_m
        return view

    def remembered_offset(self, obs: Observation, driven_ne_m: np.ndarray | None = None) -> tuple[float, float]:
        """(forward, right) from the vehicle to where the pad was last seen, in metres (moved on by
        ``driven_ne_m``: how far a moving pad has driven since, :meth:`PadMotion.moved_since`)."""
        n, e, _ = obs.position_ned_m
        pad_ne = self._pad_ne_m if driven_ne_m is None else self._pad_ne_m + driven_ne_m
        dn, de = pad_ne[0] - n, pad_ne[1] - e
        c, s = math.cos(obs.attitude_rad[2]), math.sin(obs.attitude_rad[2])
        return c * dn + s * de, -s * dn + c * de

    @staticmethod
    def _pad_position(view: PadEstimate, obs: Observation) -> np.ndarray:
        n, e, _ = obs.position_ned_m
        return pad_ground_position(view.forward_m, view.right_m, (n, e), float(obs.attitude_rad[2]))


class PadLead:
    """What ``lead_moving_pad`` adds to a pilot: the pad's motion, followed from whole sightings.

    ``velocity_fr`` is the pad's velocity in the heading frame; steering then damps the speed
    relative to it and holds ``lead_stick_per_m_s`` of it as a feed-forward, and a set-down goes
    to where the pad has driven since it was last believed.
    """

    def __init__(self, stick_per_m_s: float) -> None:
        self.stick_per_m_s = stick_per_m_s
        self.motion = PadMotion()

    def reset(self) -> None:
        self.motion.reset()

    def see(self, view: PadEstimate | None, obs: Observation, committed: bool) -> None:
        """Follow the pad from a whole sighting, and once committed from a partial one the commit
        believes (``set_down_by_picture``: its centre in the picture); before, a partial pad is at
        the picture's edge and its centre jumps."""
        if view is not None and (not view.partial or committed):
            n, e, _ = obs.position_ned_m
            self.motion.update(pad_ground_position(view.forward_m, view.right_m, (n, e), float(obs.attitude_rad[2])),
                               int(obs.time_boot_ms))

    def velocity_fr(self, obs: Observation) -> np.ndarray:
        """The pad's (forward, right) velocity for the vehicle's heading, m/s."""
        return heading_frame(self.motion.velocity_ne_at(int(obs.time_boot_ms)), float(obs.attitude_rad[2]))

    def driven_since(self, since_ms: int, obs: Observation) -> np.ndarray:
        return self.motion.moved_since(since_ms, int(obs.time_boot_ms))


class ScriptedExpert(HumanInput):
    """Centre over the pad, descend, slow down near touchdown, land. Always holds the override.

    Gains are in stick units (per metre of offset, per m/s of speed), as a person would learn
    them for a given vehicle. Memory: a trim that grows while an offset lasts (as a pilot
    leans on the stick against a drift), the last command (a blink of the detector changes
    nothing), and whether it has committed to touchdown (then it sets down where it last saw
    the pad whole, ignoring partial glimpses). With ``lead_moving_pad`` (:class:`PadLead`) also
    the pad's own motion: speeds are judged relative to the pad, the pad's speed is held as a
    driver holds a lane's, and the set-down goes where the pad has driven to. With
    ``judge_drift_by_picture`` (:class:`PictureDrift`) the drift the ground-speed reading does not
    show, seen as the pad sliding across the picture: the speed damped is the motion relative to
    the pad, the pilot leans against the drift (``lead_stick_per_m_s`` per m/s) instead of a
    trim, and a partial pad off-centre slows the set-down as in the air.
    """

    def __init__(self, cfg: PilotConfig) -> None:
        self.cfg = cfg
        self._commit = TouchdownCommit(cfg, by_picture=cfg.set_down_by_picture)
        self._lead = PadLead(cfg.lead_stick_per_m_s) if cfg.lead_moving_pad else None
        self._drift = PictureDrift(cfg.drift_time_constant_s) if cfg.judge_drift_by_picture else None
        self.reset()

    def reset(self) -> None:
        self._commit.reset()
        if self._lead is not None:
            self._lead.reset()
        if self._drift is not None:
            self._drift.reset()
        self._drift_fr = np.zeros(2)  # forward, right; m/s (judge_drift_by_picture)
        self._height_m = math.inf  # dead-reckoned height above the pad (judge_drift_by_picture)
        self._height_ms: int | None = None
        self._last_seen_ms: int | None = None
        self._last_command = JoystickCommand.neutral()
        self._trim = np.zeros(2)  # forward, right; stick units

    def read(self, obs: Observation) -> HumanCommand:
        return HumanCommand(self.command(obs), override_held=True)

    def command(self, obs: Observation) -> JoystickCommand:
        """The expert's sticks for this observation (also used when only watching)."""
        yaw_rad = float(obs.attitude_rad[2])
        vel = heading_velocity(obs.velocity_ned_m_s, yaw_rad)
        now_ms = int(obs.time_boot_ms)
        view = self._commit.update(view_of(obs, self.cfg), obs)
        if self._drift is not None:
            view = self._judged_height(view, obs)
        lead = np.zeros(2)
        if self._lead is not None:
            self._lead.see(view, obs, self._commit.committed)
            lead = self._lead.velocity_fr(obs)
        if self._drift is not None:
            seen = view if view is not None and (not view.partial or self._commit.committed) else None
            self._drift.see(seen, now_ms, yaw_rad, (obs.velocity_ned_m_s[0], obs.velocity_ned_m_s[1]))
            self._drift_fr = self._drift.drift_fr(yaw_rad, now_ms)
        if view is None and self._commit.committed:
            return self._set_down(obs, vel, lead)
        if view is None:
            return self._pad_lost(vel, now_ms, lead)
        self._update_trim(view, now_ms)
        self._last_seen_ms = now_ms
        pitch = self._steer(view.forward_m, vel[0], self._trim[0], lead[0])
        roll = self._steer(view.right_m, vel[1], self._trim[1], lead[1], axis=1)
        descent = self._descent(view)
        if view.partial and self._commit.committed:  # a partial pad's radius says little of the height
            # set down by the picture (by_picture): steadily, as the blind set-down descends; without it
            # (a partial pad seen as the commit is made) as before, so committed results rerun
            # (judging the drift: slower while off-centre, as in the air, so the pad's centre stays in the picture)
            steady = self._commit.by_picture and self._drift is None
            descent = self.cfg.descent_stick_slow if steady else min(descent, self.cfg.descent_stick_slow)
        self._last_command = JoystickCommand(roll, pitch, 0.0, -descent)
        return self._last_command

    def _judged_height(self, view: PadEstimate | None, obs: Observation) -> PadEstimate | None:
        """judge_drift_by_picture: a partial pad sized by the height dead-reckoned from where the
        pad was last seen whole (minus the descent since, by the climb-rate reading). A partial
        pad's own size says little of the height (PX4 SIH: seen as if from 0.33-0.6 m at 0.27-0.94 m),
        and its offset scales with the height: the set-down steered too little, and the drift
        judged from it jumped by 0.3 m/s (results/real-autopilots/RENDER.md)."""
        now_ms = int(obs.time_boot_ms)
        last, self._height_ms = self._height_ms, now_ms
        if view is not None and not view.partial:
            self._height_m = view.height_m
        elif last is not None and math.isfinite(self._height_m):
            self._height_m = max(0.0, self._height_m - float(obs.velocity_ned_m_s[2]) * (now_ms - last) / 1000.0)
        if view is None or not view.partial or not math.isfinite(self._height_m) or not self._commit.committed:
            return view
        scale = self._height_m / max(view.height_m, 1e-3)
        return replace(view, forward_m=view.forward_m * scale, right_m=view.right_m * scale, height_m=self._height_m)

    def reset_trim(self) -> None:
        """Forget the trim: at a take-over the pilot's hands start from what they see now, not
        from a drift they integrated while only watching the policy."""
        self._trim = np.zeros(2)

    def _update_trim(self, view: PadEstimate, now_ms: int) -> None:
        if self._drift is not None:
            # No trim: the drift is leaned against as it is seen. A trim learned from the offsets the
            # drift left before it was judged leaned against it a second time, and with PX4 SIH's
            # velocity loop (1.1 s behind) it wound up and circled the pad; the velocity loops of the
            # vehicles flown here (PX4, ArduCopter, our SITL) trim a steady wind themselves
            # (results/real-autopilots/RENDER.md, "Judging the drift from the picture").
            return
        last = self._last_seen_ms
        dt_s = 0.0 if last is None else min(max(0.0, (now_ms - last) / 1e3), 1.0)
        offset = np.array([view.forward_m, view.right_m])
        limit = self.cfg.xy_trim_max
        self._trim = np.clip(self._trim + self.cfg.xy_trim_per_m_s * offset * dt_s, -limit, limit)

    def _centred_within_m(self, view: PadEstimate) -> float:
        """The offset that counts as centred at the view's height (full descent within it)."""
        return max(self.cfg.centre_tolerance_m, self.cfg.descent_cone * view.height_m)

    def _steer(self, offset_m: float, speed_m_s: float, trim: float, lead_m_s: float = 0.0, axis: int = 0) -> float:
        """Stick on one ``axis`` (0 forward, 1 right). Leading a pad that drives at ``lead_m_s``:
        damp the speed relative to it and hold its speed's stick, steering within
        ``xy_stick_max`` of that; judging the drift by the picture, the same with the drift."""
        c = self.cfg
        if self._drift is not None:  # speed relative to the pad; lean against the drift
            drift = self._drift_fr[axis]
            demand = c.xy_gain_per_m * offset_m - c.xy_damping_per_m_s * (speed_m_s + drift) + trim
            return float(np.clip(-c.lead_stick_per_m_s * drift + _stick(demand, c.xy_stick_max), -1.0, 1.0))
        if self._lead is None:
            demand = c.xy_gain_per_m * offset_m - c.xy_damping_per_m_s * speed_m_s + trim
            return _stick(demand, c.xy_stick_max)
        hold = self._lead.stick_per_m_s * lead_m_s
        demand = c.xy_gain_per_m * offset_m - c.xy_damping_per_m_s * (speed_m_s - lead_m_s) + trim
        return float(np.clip(hold + _stick(demand, c.xy_stick_max), -1.0, 1.0))

    def _descent(self, view: PadEstimate) -> float:
        """Descent stick: fast when high, slow near the pad, less while off-centre."""
        c = self.cfg
        blend = np.clip((view.height_m - c.slow_height_m) / c.slow_height_m, 0.0, 1.0)
        rate = c.descent_stick_slow + (c.descent_stick_fast - c.descent_stick_slow) * blend
        allowed_m = self._centred_within_m(view)
        centred = np.clip(2.0 - view.offset_m / allowed_m, 0.0, 1.0)
        return float(rate * centred)

    def _pad_lost(self, vel: np.ndarray, now_ms: int, lead: np.ndarray) -> JoystickCommand:
        """A blink: carry on. Longer: brake (keeping the trim; leading, to the pad's speed) and
        climb to see more."""
        seen = self._last_seen_ms
        if seen is not None and now_ms - seen < self.cfg.lost_hold_s * 1000.0:
            return self._last_command
        pitch = self._steer(0.0, vel[0], self._trim[0], lead[0])
        roll = self._steer(0.0, vel[1], self._trim[1], lead[1], axis=1)
        return JoystickCommand(roll, pitch, 0.0, self.cfg.search_climb_stick)

    def _set_down(self, obs: Observation, vel: np.ndarray, lead: np.ndarray) -> JoystickCommand:
        """Committed, pad not seen whole: steer to where it was (leading: to where it has driven
        to since), descend slowly."""
        driven = None if self._lead is None else self._lead.driven_since(self._commit.seen_ms, obs)
        forward_m, right_m = self._commit.remembered_offset(obs, driven)
        pitch = self._steer(forward_m, vel[0], self._trim[0], lead[0])
        roll = self._steer(right_m, vel[1], self._trim[1], lead[1], axis=1)
        return JoystickCommand(roll, pitch, 0.0, -self.cfg.descent_stick_slow)


class ProgressWatch:
    """Whether the descent has stalled: less than ``min_descent_m`` lower over ``stall_s``.

    Uses the altitude a pilot reads off the ground station (local NED ``down``). A stall
    time of 0 disables it.
    """

    def __init__(self, stall_s: float, min_descent_m: float) -> None:
        self.stall_ms = stall_s * 1000.0
        self.min_descent_m = min_descent_m
        self.restart()

    def restart(self) -> None:
        """Measure progress from the next observation on."""
        self._since: tuple[int, float] | None = None

    def stalled(self, obs: Observation) -> bool:
        now_ms, down_m = int(obs.time_boot_ms), float(obs.position_ned_m[2])
        if self._since is None or down_m >= self._since[1] + self.min_descent_m:
            self._since = (now_ms, down_m)
            return False
        return self.stall_ms > 0 and now_ms - self._since[0] > self.stall_ms


@dataclass(frozen=True)
class RuleState:
    """What the intervention rule concluded at one tick (for logs and tests)."""

    holding: bool
    reason: str | None
    """Why the expert is (still) holding, or None when the agent flies."""


def projected_miss_m(view: PadEstimate, velocity_fr_m_s: np.ndarray, descent_m_s: float,
                     horizon_s: float) -> float | None:
    """Where a watching person expects the touchdown: the pad's offset after the vehicle keeps
    its ground velocity until it reaches the pad's height (None: no touchdown within
    ``horizon_s``, e.g. hovering or high up: nothing to predict yet).

    People anticipate a miss from the motion they see; waiting for the pad to reach the image
    edge (the other take-over triggers) acts only a metre above the pad.
    """
    if descent_m_s <= 0.05 or view.height_m > descent_m_s * horizon_s:
        return None
    t_s = view.height_m / descent_m_s
    return math.hypot(view.forward_m - float(velocity_fr_m_s[0]) * t_s,
                      view.right_m - float(velocity_fr_m_s[1]) * t_s)


class InterventionRule:
    """When a watching expert takes over, and when they let go.

    Take over at once when: the vehicle descends faster than ``takeover_descent_m_s`` (or
    than ``takeover_low_descent_m_s`` below ``takeover_low_height_m``); the pad has been lost
    for ``lost_hold_s``; the pad drifts towards the image edge (``takeover_edge_fraction``);
    it is off-centre by more than ``takeover_off_centre_m`` below ``takeover_low_height_m``;
    the touchdown expected within ``anticipation_s`` is projected (:func:`projected_miss_m`)
    more than ``takeover_predicted_miss_m`` from the pad's centre; or the descent stalls (less than
    ``takeover_stall_descent_m`` in ``takeover_stall_s``: a watching person loses patience).
    Once committed to touchdown (:class:`TouchdownCommit`) a partial or missing pad is
    expected, and sliding (``takeover_touchdown_speed_m_s``) or drifting off the remembered
    pad position is the danger.

    Let go after ``release_hold_s`` of being back on track: at least ``release_descent_m``
    lower than at the take-over, pad within ``release_edge_fraction`` and, when low, within
    ``release_off_centre_m`` (tighter than the take-over thresholds, so the rule does not
    chatter). Nobody hands back control while setting the vehicle down: once committed, the
    expert keeps the sticks until touchdown. With ``lead_moving_pad`` (:class:`PadLead`) the
    speeds that warn (sliding, the projected miss) are relative to the pad, and the remembered
    pad drives on.
    """

    def __init__(self, cfg: PilotConfig) -> None:
        self.cfg = cfg
        self.reset()

    def reset(self) -> None:
        self._holding = False
        self._on_track_since_ms: int | None = None
        self._takeover_down_m = 0.0
        self._last_seen_ms: int | None = None
        self._commit = TouchdownCommit(self.cfg)
        self._lead = PadLead(self.cfg.lead_stick_per_m_s) if self.cfg.lead_moving_pad else None
        self._progress = ProgressWatch(self.cfg.takeover_stall_s, self.cfg.takeover_stall_descent_m)
        self.takeovers = 0

    def update(self, obs: Observation) -> RuleState:
        """Advance the rule by one observation."""
        view = self._commit.update(view_of(obs, self.cfg), obs)
        if self._lead is not None:
            self._lead.see(view, obs, self._commit.committed)
        if obs.pad is not None:
            self._last_seen_ms = int(obs.time_boot_ms)
        stalled = self._progress.stalled(obs)
        danger = self._danger(obs, view) or ("not descending" if stalled else None)
        if not self._holding:
            if danger is not None:
                self._holding, self._on_track_since_ms = True, None
                self._takeover_down_m = float(obs.position_ned_m[2])
                self._progress.restart()
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

    def take_over(self, obs: Observation) -> RuleState:
        """Asked for help: advance by one observation and hold the sticks whatever it shows
        (let go by the usual release rule)."""
        state = self.update(obs)
        if state.holding:
            return state
        self._holding, self._on_track_since_ms = True, None
        self._takeover_down_m = float(obs.position_ned_m[2])
        self._progress.restart()
        self.takeovers += 1
        return RuleState(True, "asked for help")

    def _danger(self, obs: Observation, view: PadEstimate | None) -> str | None:
        c = self.cfg
        vn, ve, vd = (float(v) for v in obs.velocity_ned_m_s)
        if vd > c.takeover_descent_m_s:
            return "descending too fast"
        if view is not None and view.height_m < c.takeover_low_height_m and vd > c.takeover_low_descent_m_s:
            return "descending too fast near the ground"
        if self._lead is not None:  # speeds relative to the pad
            vn, ve = np.array([vn, ve]) - self._lead.motion.velocity_ne_at(int(obs.time_boot_ms))
        if view is None and self._commit.committed:
            if math.hypot(vn, ve) > c.takeover_touchdown_speed_m_s:
                return "sliding sideways at touchdown"
            driven = None if self._lead is None else self._lead.driven_since(self._commit.seen_ms, obs)
            if math.hypot(*self._commit.remembered_offset(obs, driven)) > c.takeover_off_centre_m:
                return "drifting off the pad at touchdown"
            return None  # right above the pad: a glimpse of its rim says little
        if view is None:
            seen = self._last_seen_ms
            lost_ms = math.inf if seen is None else int(obs.time_boot_ms) - seen
            return "pad lost" if lost_ms >= c.lost_hold_s * 1000.0 else None
        if view.edge_fraction > c.takeover_edge_fraction:
            return "pad near the image edge"
        if view.height_m < c.takeover_low_height_m and view.offset_m > c.takeover_off_centre_m:
            return "off-centre at low height"
        miss_m = projected_miss_m(view, heading_velocity((float(vn), float(ve), vd), float(obs.attitude_rad[2])),
                                  vd, c.anticipation_s)
        if c.takeover_predicted_miss_m > 0 and miss_m is not None and miss_m > c.takeover_predicted_miss_m:
            return "heading for a miss"
        return None

    def _on_track(self, obs: Observation, view: PadEstimate | None) -> bool:
        """Called only when there is no danger: is the vehicle also well placed?"""
        c = self.cfg
        if self._commit.committed:
            return False  # nobody hands back control while setting the vehicle down
        if float(obs.position_ned_m[2]) < self._takeover_down_m + c.release_descent_m:
            return False
        if view is None:
            return False
        low = view.height_m < c.takeover_low_height_m
        return view.edge_fraction <= c.release_edge_fraction and (
            not low or view.offset_m <= c.release_off_centre_m
        )


class InterveningExpert(HumanInput):
    """A synthetic operator for interventions: the expert's sticks, override by the rule."""

    def __init__(self, cfg: PilotConfig) -> None:
        self.expert = ScriptedExpert(cfg)
        self.rule = InterventionRule(cfg)
        self.last_state = RuleState(False, None)
        self._asked = False

    def reset(self) -> None:
        self.expert.reset()
        self.rule.reset()
        self.last_state = RuleState(False, None)
        self._asked = False

    def take_over_now(self) -> None:
        """Asked for help: take the sticks at the next read, whatever the rule sees."""
        self._asked = True

    def read(self, obs: Observation) -> HumanCommand:
        was_holding = self.last_state.holding
        self.last_state = self.rule.take_over(obs) if self._asked else self.rule.update(obs)
        self._asked = False
        if self.last_state.holding and not was_holding:
            self.expert.reset_trim()  # a take-over label depends on what is seen now only
        cmd = self.expert.command(obs)  # every tick, so the expert's memory stays current
        return HumanCommand(cmd, override_held=self.last_state.holding)
