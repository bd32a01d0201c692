"""Touchdowns that the vehicle's own land detector recognises, whoever flies.

Real PX4 (MulticopterLandDetector) registers ground contact in velocity-controlled flight only
while the commanded descent is at least 1.1 x ``LNDMC_Z_VEL_MAX`` (0.25 m/s by default). The
expert's slow final descent (0.263 m/s) and the policies that learned it sat on the ground,
armed, until the episode timed out. ArduCopter's detector needs no descent rate: it waits for
its throttle to reach the lower limit with the vehicle still, which any asked descent gives.

The companion does not change what a person or a policy asks for in the air (the dataset and
the policy stay as they are): :class:`TouchdownAssist` sits after the limiter and acts only once
the evidence says the vehicle stands on a surface: asked down, not moving vertically, for
``assist_after_s``, no higher than a little above the pad. Then it asks down at what the
detector needs, times a margin, or at the vehicle's own landing descent if that is faster. Touchdown itself is the vehicle's landed state
(EXTENDED_SYS_STATE ON_GROUND); only a vehicle that never reports one is judged by this
evidence (``evidence_touchdown_s`` of it).

:class:`VehicleTouchdown` makes a vehicle's assist at its first episode, from the land-detector
parameters the vehicle itself gives (asked once), and starts it afresh at every episode.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from companion.config import LandingConfig
from companion.control.truth_contact import TruthGround
from companion.errors import ColError
from companion.link.base import VehicleLink
from companion.link.home import HomeFrame
from companion.msg.setpoint import VelocitySetpoint
from companion.msg.snapshot import VehicleSnapshot

log = logging.getLogger(__name__)
PX4_CONTACT_FACTOR = 1.1  # PX4: ground contact needs the commanded descent >= 1.1 x LNDMC_Z_VEL_MAX
PX4_LNDMC_Z_VEL_MAX_DEFAULT = 0.25
MAX_LAND_SPEED_M_S = 1.0  # a land speed beyond this is not asked of a vehicle standing on a surface
CONTACT_RANGE_M = 0.1  # a downward rangefinder this close to the surface: standing on it
RANGE_FRESH_S = 0.5
RANGE_CONTACT_STEPS = 3  # consecutive steps of rangefinder contact (noise of one reading is not contact)  # a rangefinder reading older than this says nothing
RELEASE_CLIMB_M = 0.5  # engaged, and then this much higher: it was not standing after all
TRUTH_CONTACT_NOTE = "touchdown judged by the SITL's truth: first ground contact (the rendered pad is no surface)"
ASKED_DOWN_M_S = 0.02  # a setpoint this slow downwards still counts as someone asking to descend


@dataclass(frozen=True)
class TouchdownNeed:
    """The slowest commanded descent at which the vehicle's land detector fires (0: any), and
    the descent its own landing mode asks for (0: unknown)."""

    min_descent_m_s: float
    why: str
    land_speed_m_s: float = 0.0


def touchdown_need(autopilot: str, read_param: Callable[[str], float | None],
                   configured_m_s: float = 0.0) -> TouchdownNeed:
    """What this autopilot's land detector needs, from its own parameters where it has them.

    ``read_param`` asks the vehicle (PARAM protocol) and returns None without an answer;
    ``configured_m_s`` > 0 overrides what the vehicle says.
    """
    if configured_m_s > 0:
        return TouchdownNeed(configured_m_s, f"[companion.landing] min_descent_m_s = {configured_m_s:g}")
    if autopilot == "PX4":
        value = read_param("LNDMC_Z_VEL_MAX")
        if value is None or not math.isfinite(value) or value <= 0:
            value, said = PX4_LNDMC_Z_VEL_MAX_DEFAULT, f"PX4's default LNDMC_Z_VEL_MAX {PX4_LNDMC_Z_VEL_MAX_DEFAULT:g} (the vehicle did not say)"
        else:
            said = f"the vehicle's LNDMC_Z_VEL_MAX {value:g}"
        need = PX4_CONTACT_FACTOR * value
        land = read_param("MPC_LAND_SPEED")
        land_m_s = land if land is not None and math.isfinite(land) and 0 < land <= MAX_LAND_SPEED_M_S else 0.0
        return TouchdownNeed(need, f"PX4 registers ground contact only at a descent >= 1.1 x {said} m/s = {need:.3f} m/s"
                             + (f"; its own landing asks MPC_LAND_SPEED {land_m_s:g} m/s" if land_m_s else ""), land_m_s)
    if autopilot == "ARDUPILOTMEGA":
        land_speed = read_param("LAND_SPEED")  # cm/s: LAND mode's final descent, for the log
        said = f" (its LAND mode descends at LAND_SPEED {land_speed / 100:.2f} m/s)" if land_speed else ""
        return TouchdownNeed(0.0, "ArduCopter's land detector needs the throttle at its lower limit, "
                                  f"not a descent rate{said}")
    return TouchdownNeed(0.0, f"no known descent rule for autopilot {autopilot}")


class TouchdownAssist:
    """After the limiter: a too-slow descent on a surface becomes the descent the detector needs.

    "Standing on a surface": over the last ``assist_after_s`` the vehicle was asked down at every
    step but came down less than half of what it was asked (PX4 SIH's vertical speed on the
    ground is noisy, +-0.15 m/s, so a window of heights judges, not one speed), no higher than
    ``assist_height_m`` above the pad's height above home. Once standing, the assist holds while
    the vehicle is asked down and does not climb away; asked anything else, it lets go.
    """

    def __init__(self, need: TouchdownNeed, cfg: LandingConfig, period_s: float, pad_height_m: float,
                 home: HomeFrame, max_down_m_s: float = math.inf) -> None:
        self.need, self.cfg, self.home, self.period_s = need, cfg, home, period_s
        # the vehicle's own landing descent, where it says: on real PX4 SIH 0.33 m/s (1.2 x the
        # minimum) on the ground left its estimate sinking at 0.1-0.2 m/s, the thrust near hover
        # and the detector waiting for 10 s and more; at MPC_LAND_SPEED (0.7) its AUTO.LAND lands in 2-4 s
        wanted = max(need.min_descent_m_s * cfg.descent_margin, need.land_speed_m_s) if need.min_descent_m_s > 0 else 0.0
        self.wanted_m_s = min(wanted, max_down_m_s)
        """What it asks; never more than the limiter lets through (``max_down_m_s``, the commands'
        v_z_max): it comes after the limiter, so it keeps to the limiter's bounds itself."""
        self.window_steps = max(2, math.ceil(cfg.assist_after_s / period_s - 1e-9))
        self.evidence_steps = max(1, math.ceil(cfg.evidence_touchdown_s / period_s - 1e-9))
        self.below_height_m = max(0.0, pad_height_m) + cfg.assist_height_m
        self.engaged_steps_total = 0
        self.reset()

    @property
    def active(self) -> bool:
        """Whether this vehicle needs it at all (a detector with a descent rule, assist on)."""
        return self.cfg.touchdown_assist and self.wanted_m_s > 0

    def reset(self) -> None:
        self._window: deque[tuple[float, float]] = deque(maxlen=self.window_steps)  # (down m, asked m/s)
        self._engaged_at_m: float | None = None
        self._engaged_steps = 0
        self._range_steps = 0

    @property
    def engaged(self) -> bool:
        return self._engaged_at_m is not None

    def standing_long_enough(self) -> bool:
        """The companion's own evidence of a touchdown (for vehicles with no landed state)."""
        return self.engaged and self._engaged_steps >= self.evidence_steps

    def range_contact_long_enough(self) -> bool:
        """A downward rangefinder has read contact, asked down, for ``evidence_touchdown_s``: a
        touchdown by the companion's evidence even while the vehicle's detector, fed a drifting
        estimate, still says in the air."""
        return self._range_steps >= self.evidence_steps

    def _range_contact(self, snap: VehicleSnapshot) -> bool:
        """A fresh downward rangefinder reading at the surface (PX4 SIH has one; its height
        estimate sank by up to 1 m while the vehicle stood on the ground)."""
        d = snap.ground_distance_m
        return d is not None and d <= CONTACT_RANGE_M and snap.received_s - snap.ground_distance_s <= RANGE_FRESH_S

    def _standing(self) -> bool:
        if len(self._window) < self.window_steps:
            return False
        came_down_m = self._window[-1][0] - self._window[0][0]
        asked_m = sum(asked for _, asked in list(self._window)[1:]) * self.period_s
        return came_down_m < 0.5 * asked_m

    def apply(self, setpoint: VelocitySetpoint, snap: VehicleSnapshot) -> VelocitySetpoint:
        """The setpoint to send this step, given the newest telemetry."""
        if not self.active:
            return setpoint
        height = self.home.height(snap)
        contact = self._range_contact(snap)
        if setpoint.down_m_s <= ASKED_DOWN_M_S or (height > self.below_height_m and not contact):
            self.reset()
            return setpoint
        self._window.append((-height, setpoint.down_m_s))
        self._range_steps = self._range_steps + 1 if contact else 0
        if self._engaged_at_m is not None and height > self._engaged_at_m + RELEASE_CLIMB_M and not contact:
            self.reset()  # it climbed away: it was not standing after all
            return setpoint
        if self._engaged_at_m is None:
            if not (self._standing() or self._range_steps >= RANGE_CONTACT_STEPS):
                return setpoint
            self._engaged_at_m = height
            log.info("standing on a surface at %.2f m above home, asked down at %.3f m/s: asking %.3f m/s "
                     "so the land detector fires (%s)", height, setpoint.down_m_s, self.wanted_m_s, self.need.why)
        self._engaged_steps += 1
        self.engaged_steps_total += 1
        if setpoint.down_m_s >= self.wanted_m_s:
            return setpoint
        return VelocitySetpoint(setpoint.forward_m_s, setpoint.right_m_s, self.wanted_m_s, setpoint.yaw_rate_rad_s)


class VehicleTouchdown:
    """One vehicle's touchdown assist, made at its first episode (module docstring): ``assist``
    None while ``landing`` is not given, the assist is off, or the vehicle has not answered yet."""

    def __init__(self, landing: LandingConfig | None, period_s: float, pad_height_m: float, home: HomeFrame,
                 max_down_m_s: float, link: VehicleLink) -> None:
        self.landing, self.period_s, self.pad_height_m, self.home = landing, period_s, pad_height_m, home
        self.max_down_m_s, self.link = max_down_m_s, link
        self.assist: TouchdownAssist | None = None

    def reset(self) -> None:
        """A new episode: the assist made if it is not yet (a vehicle that cannot say yet, with no
        HEARTBEAT, is asked again at the next episode; its start reports why), and started afresh."""
        landing = self.landing
        if landing is None or not landing.touchdown_assist:
            return
        if self.assist is None:
            try:
                snap = self.link.state()
                need = touchdown_need(snap.autopilot if snap is not None else "", self.link.read_param,
                                      landing.min_descent_m_s)
            except ColError as exc:
                log.debug("touchdown assist not ready: %s", exc)
                return
            self.assist = TouchdownAssist(need, landing, self.period_s, self.pad_height_m, self.home,
                                          self.max_down_m_s)
            log.info("touchdown: %s%s", need.why,
                     f"; standing on a surface, the companion asks {self.assist.wanted_m_s:.3f} m/s"
                     if self.assist.active else "; nothing to add")
        self.assist.reset()


@dataclass(frozen=True)
class Evidence:
    """Why the companion counts the vehicle as standing: its landed state (no note), or the
    companion's own evidence (the episode record's note, and the log's longer message)."""

    note: str = ""
    message: str = ""
    stand_down: bool = False
    """The vehicle's own land detector may never fire (a SITL's truth judged the contact): the
    companion disarms it so the next start takes off from the ground."""


def touchdown_evidence(snap: VehicleSnapshot, assist: TouchdownAssist | None,
                       ground: TruthGround | None = None) -> Evidence | None:
    """Whether the vehicle stands: its landed state; where a SITL's truth is asked to judge
    (``ground``, companion/control/truth_contact.py), its first ground contact; for a vehicle that
    reports no landed state, or whose detector is fed a drifting estimate, the assist's evidence
    (each with a note); None: not."""
    if snap.landed_state == "ON_GROUND":
        return Evidence()
    if ground is not None and ground.touching(snap):
        return Evidence(TRUTH_CONTACT_NOTE,
                        f"touchdown judged by the SITL's truth: ground contact, {ground.height_m(snap):.3f} m above "
                        f"where the vehicle stood, while it said {snap.landed_state}", stand_down=True)
    if snap.landed_state == "UNDEFINED" and assist is not None and assist.standing_long_enough():
        return Evidence("touchdown judged by the companion: no landed state, standing",
                        "touchdown judged by the companion: the vehicle reports no landed state "
                        f"(EXTENDED_SYS_STATE) and has stood on a surface, asked down, for "
                        f"{assist.cfg.evidence_touchdown_s:.1f} s")
    if assist is not None and assist.active and assist.range_contact_long_enough():
        return Evidence("touchdown judged by the companion: rangefinder contact (the vehicle still said in air)",
                        "touchdown judged by the companion: its downward rangefinder has read contact for "
                        f"{assist.cfg.evidence_touchdown_s:.1f} s while the vehicle, still saying "
                        f"{snap.landed_state}, was asked down")
    return None
