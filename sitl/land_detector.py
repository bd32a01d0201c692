"""PX4's land detector (``land_detector``, LNDMC_*), the vehicle's landed state and touchdowns.

Whether the vehicle has landed, which the autopilot acts on (auto-disarm, mode refusals,
take-off handling), is decided by one of two rules (``autopilot.land_detector``): PX4's
detector (:class:`Px4LandDetector`, pure logic on the FDM state) or plain contact (still on a
surface). :class:`VehicleLandDetector` applies the rule every FDM step and judges the
touchdown (ground truth, not the autopilot's). Apart from the cascade, as PX4 runs its land
detector apart from its controllers; the cascade's tests use the miniature :class:`LandDetector`.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sitl.config import AutopilotConfig
from sitl.control import FlightController, Setpoint, wants_takeoff
from sitl.dynamics import VehicleState
from sitl.status import FlightStatus
from sitl.world import World

NAN = math.nan
LANDED_SPEED_M_S = 0.5  # slower than this (and then some, see below) on a surface: settled
LOW_LIFT_RATIO = 0.95  # land detectors' "low thrust": asking for less lift than this x weight
LANDED_WIDENING = 2.5  # PX4 widens the vertical and rotation limits once maybe landed


class LandDetector:
    """Landed = touching a surface, nearly still and asking for less lift than the weight,
    continuously for ``hold_s`` (PX4's land detector in miniature; the cascade's tests use it,
    the vehicle :class:`VehicleLandDetector`)."""

    def __init__(
        self,
        dt_s: float,
        hold_s: float = 0.3,
        max_speed_m_s: float = 0.3,
        max_lift_ratio: float = 0.95,
    ) -> None:
        self.dt_s = dt_s
        self.hold_s = hold_s
        self.max_speed_m_s = max_speed_m_s
        self.max_lift_ratio = max_lift_ratio
        self.reset()

    def reset(self) -> None:
        self._still_s = 0.0
        self.landed = False

    def update(self, state: VehicleState, lift_ratio: float, armed: bool = True) -> bool:
        """Feed one step; ``lift_ratio`` is :attr:`FlightController.lift_ratio` (0 if off)."""
        vn, ve, vd = state.velocity_ned_m_s
        still = (
            state.on_ground
            and vn * vn + ve * ve + vd * vd < self.max_speed_m_s**2
            and (not armed or lift_ratio < self.max_lift_ratio)
        )
        self._still_s = self._still_s + self.dt_s if still else 0.0
        self.landed = self._still_s >= self.hold_s
        return self.landed


class _Hysteresis:
    """True once its condition has held ``delay_s``, false as soon as it fails (PX4's
    systemlib::Hysteresis as its land detector sets it up)."""

    __slots__ = ("state", "delay_s", "_since_s")

    def __init__(self, delay_s: float) -> None:
        self.delay_s = delay_s
        self.reset(False)

    def reset(self, state: bool) -> None:
        self.state = state
        self._since_s = NAN

    def update(self, condition: bool, now_s: float) -> None:
        if not condition:
            self.state = False
            self._since_s = NAN
        elif not self.state:
            if self._since_s != self._since_s:  # NaN: the condition begins now
                self._since_s = now_s
            self.state = now_s - self._since_s >= self.delay_s - 1e-9  # steps of 1/126 s: 42 = 1/3 s


class Px4LandDetector:
    """PX4's multicopter land detector (LNDMC_*), in climb-rate-controlled flight (every mode
    the SITL flies). Three stages, each true once its condition held LNDMC_TRIG_TIME / 3, false
    as soon as it fails, judged (as PX4 does) with the stages of the previous step:

    1. ground contact: no vertical movement (|vz| <= LNDMC_Z_VEL_MAX, 2.5x once maybe landed),
       no horizontal movement (<= LNDMC_XY_VEL_MAX) and, until maybe landed, a commanded descent
       (the setpoint's vz) of at least 1.1 x LNDMC_Z_VEL_MAX: the velocity loop pushing down;
    2. maybe landed: ground contact, low thrust (lift asked < 0.95 weight) and roll/pitch rates
       <= LNDMC_ROT_MAX (2.5x once maybe landed);
    3. landed: maybe landed.

    Disarmed, every condition holds. It sees what PX4's estimator sees, not ``on_ground``: told
    to descend slower than 1.1 x LNDMC_Z_VEL_MAX, a vehicle sits on the ground armed and never
    lands, as real PX4 does. Runs every FDM step: plain floats, no allocations.
    """

    def __init__(self, cfg: AutopilotConfig) -> None:
        self._contact = _Hysteresis(0.0)
        self._maybe = _Hysteresis(0.0)
        self._landed = _Hysteresis(0.0)
        self.configure(cfg)

    def configure(self, cfg: AutopilotConfig) -> None:
        """New LNDMC_* values (a parameter changed); the stages keep their state."""
        self._z_max = cfg.land_z_vel_max_m_s
        self._descent_min = 1.1 * cfg.land_z_vel_max_m_s
        self._xy_max2 = cfg.land_xy_vel_max_m_s**2
        self._rot_max2 = math.radians(cfg.land_rot_max_deg_s) ** 2
        stage_s = cfg.land_trigger_time_s / 3.0
        self._contact.delay_s = self._maybe.delay_s = self._landed.delay_s = stage_s

    def reset(self, landed: bool) -> None:
        """Every stage at once: landed (boot, on the ground) or flying (an episode's start)."""
        self._contact.reset(landed)
        self._maybe.reset(landed)
        self._landed.reset(landed)

    @property
    def ground_contact(self) -> bool:
        return self._contact.state

    @property
    def maybe_landed(self) -> bool:
        return self._maybe.state

    @property
    def landed(self) -> bool:
        return self._landed.state

    def update(self, state: VehicleState, descent_sp_m_s: float, lift_ratio: float, armed: bool) -> bool:
        """Feed one step; ``descent_sp_m_s`` is the setpoint's vz (down positive, NaN: none),
        ``lift_ratio`` :attr:`FlightController.lift_ratio`. Returns :attr:`landed`."""
        contact = not armed or self._ground_contact(state, descent_sp_m_s)
        maybe = not armed or self._maybe_landed(state, lift_ratio)
        landed = not armed or self._maybe.state
        now_s = state.time_s
        self._contact.update(contact, now_s)
        self._maybe.update(maybe, now_s)
        self._landed.update(landed, now_s)
        return self._landed.state

    def _ground_contact(self, state: VehicleState, descent_sp_m_s: float) -> bool:
        vn, ve, vd = state.velocity_ned_m_s
        widened = self._maybe.state
        z_max = self._z_max * LANDED_WIDENING if widened else self._z_max
        if vd > z_max or vd < -z_max or vn * vn + ve * ve > self._xy_max2:
            return False
        # NaN (no velocity setpoint, e.g. a position alone) is no commanded descent
        return widened or self._landed.state or descent_sp_m_s >= self._descent_min

    def _maybe_landed(self, state: VehicleState, lift_ratio: float) -> bool:
        if not self._contact.state or lift_ratio >= LOW_LIFT_RATIO:
            return False
        p, q, _ = state.rates_frd_rad_s
        rot2 = self._rot_max2 * (LANDED_WIDENING * LANDED_WIDENING) if self._maybe.state else self._rot_max2
        return p * p + q * q <= rot2


class VehicleLandDetector:
    """The vehicle's landed state, by its rule, and its touchdowns, every FDM step.

    A touchdown is the first settling contact after flight: slower than 0.5 m/s plus twice the
    last step's descent (a bounce is not settling). With the contact rule that contact is
    "landed" too; with PX4's rule :class:`Px4LandDetector` decides, fed the setpoint's commanded
    descent and the thrust asked for.

    ``carried_velocity`` (``[sitl.world] roof_carries``): the velocity of the surface that carries
    the vehicle now; the settling speed and the touchdown's speed are then relative to it (on the
    driving roof the vehicle settles at the roof's speed). PX4's rule keeps the world's velocity,
    which is what PX4's estimator measures on a moving platform.
    """

    def __init__(self, status: FlightStatus, px4: Px4LandDetector, px4_rule: bool, world: World,
                 controller: FlightController, say: Callable[[int, str], None],
                 carried_velocity: Callable[[], tuple[float, float]] | None = None) -> None:
        self.status = status
        self.carried_velocity = carried_velocity
        self.px4 = px4
        self.px4_rule = px4_rule
        self.world = world
        self.controller = controller
        self.say = say
        self._airborne = False
        self._last_down_speed_m_s = 0.0

    def configure(self, cfg: AutopilotConfig) -> None:
        self.px4.configure(cfg)

    def reset(self, landed: bool) -> None:
        """Landed (boot: on the ground since time 0) or flying (an episode's start, in the air)."""
        self.status.landed_since_s = 0.0 if landed else None
        self._airborne = not landed
        self._last_down_speed_m_s = 0.0
        self.px4.reset(landed=landed)

    def idles(self, state: VehicleState, sp: Setpoint, armed: bool) -> bool:
        """With PX4's rule a landed vehicle idles until a setpoint asks it to take off (PX4's
        take-off handling)."""
        return self.px4_rule and armed and self.px4.landed and not wants_takeoff(state, sp)

    def update(self, s: VehicleState) -> None:
        """After the FDM step to ``s``: the touchdown, and the landed state by the rule."""
        st = self.status
        contact_rule = not self.px4_rule
        vn, ve, vd = s.velocity_ned_m_s
        if self.carried_velocity is not None:  # relative to the surface that carries it
            fn, fe = self.carried_velocity()
            vn, ve = vn - fn, ve - fe
        speed = math.sqrt(vn * vn + ve * ve + vd * vd)
        if s.on_ground and speed < LANDED_SPEED_M_S + 2.0 * abs(self._last_down_speed_m_s):
            if self._airborne and st.touchdown is None:
                self._judge_touchdown(s, speed)
            self._airborne = False
            if contact_rule and st.landed_since_s is None:
                st.landed_since_s = s.time_s
        elif not s.on_ground:
            self._airborne = True
            if contact_rule:
                st.landed_since_s = None
        if not contact_rule:
            self._detect_px4(s)
        self._last_down_speed_m_s = vd

    def _judge_touchdown(self, s: VehicleState, speed: float) -> None:
        td_speed = max(speed, self._last_down_speed_m_s)
        td = self.world.judge(np.asarray(s.position_ned_m), td_speed, s.time_s)
        self.status.touchdown = td
        verdict = "on the pad" if td.success else "off the pad"
        self.say(mavlink.MAV_SEVERITY_NOTICE, f"Touchdown {verdict}, {td.distance_to_pad_m:.2f} m")

    def _detect_px4(self, s: VehicleState) -> None:
        st = self.status
        if not self.px4.update(s, st.setpoint.velocity_ned_m_s[2], self.controller.lift_ratio, st.armed):
            st.landed_since_s = None
        elif st.landed_since_s is None:
            st.landed_since_s = s.time_s
