"""PX4's commander: arming, mode requests and transitions, take-off, landing, auto-disarm.

It decides what the vehicle is asked to do and whether it may; the cascade (sitl/control.py)
decides how it flies. Entering a mode captures the setpoint it flies (hold, land, take-off:
from the pose now), as PX4's navigator does on entry. The ArduCopter personality derives its
own (sitl/personality.py).
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink

from sitl.control import Setpoint
from sitl.dynamics import VehicleState
from sitl.modes import Mode, refusal
from sitl.status import VehicleView, hold_setpoint

NAN = math.nan
FORCE_DISARM_MAGIC = 21196  # COMPONENT_ARM_DISARM param2: disarm even in the air
PREFLIGHT_DISARM_S = 10.0  # COM_DISARM_PRFLT: armed and not taken off this long -> disarm
LAND_DISARM_S = 0.5  # AUTO.LAND and AUTO.PRECLAND disarm this long after landing
TAKEOFF_REACHED_M = 0.15  # AUTO.TAKEOFF is done this close to its height

Result = tuple[int, str]
"""A command's MAV_RESULT and, when refused, why (sent as STATUSTEXT)."""


class Commander:
    """Arms and disarms, switches modes and runs the commands that do (PX4's rules)."""

    takeoff_alt_m = 2.5
    """AUTO.TAKEOFF's height above the surface below: the last NAV_TAKEOFF's (kept across episodes)."""

    def __init__(self, v: VehicleView) -> None:
        self.v = v
        self.status = v.status

    # ----- modes -------------------------------------------------------------------------
    def set_mode_numbers(self, main: int, sub: int) -> Result:
        """Personality: MAV_CMD_DO_SET_MODE's param2 and param3 (PX4: main and sub mode)."""
        try:
            mode = Mode.from_main_sub(main, sub)
        except ValueError as exc:
            return mavlink.MAV_RESULT_DENIED, str(exc)
        return self.request_mode(mode)

    def set_mode_custom(self, custom_mode: int) -> Result:
        """Personality: the SET_MODE message's custom_mode."""
        try:
            mode = Mode.from_custom_mode(custom_mode)
        except ValueError as exc:
            return mavlink.MAV_RESULT_DENIED, str(exc)
        return self.request_mode(mode)

    def setpoints_fresh(self) -> bool:
        """An offboard setpoint arrived within COM_OF_LOSS_T: OFFBOARD may be entered."""
        return self.v.time_s - self.status.last_offboard_s <= self.v.params.get("COM_OF_LOSS_T")

    def request_mode(self, mode: Mode) -> Result:
        st = self.status
        why = refusal(mode, armed=st.armed, landed=st.landed, setpoints_fresh=self.setpoints_fresh())
        if why:
            return mavlink.MAV_RESULT_DENIED, why
        st.offboard_lost_s = None  # a mode asked for takes over from the failsafe
        if mode is st.mode:
            return mavlink.MAV_RESULT_ACCEPTED, ""
        if mode is Mode.OFFBOARD:
            self.resume_offboard()
        else:
            self.enter(Mode.POSCTL if mode in (Mode.MANUAL, Mode.ALTCTL) else mode)
        self.v.say(mavlink.MAV_SEVERITY_INFO, f"Mode {st.mode.px4_name}")
        return mavlink.MAV_RESULT_ACCEPTED, ""

    def resume_offboard(self) -> None:
        """OFFBOARD, flying the latest setpoint (asked for, or the stream back after a loss)."""
        st = self.status
        st.mode = Mode.OFFBOARD
        st.setpoint = st.latest_offboard_sp or hold_setpoint(self.v.estimate)
        st.failsafe_since_s = st.offboard_lost_s = None

    def enter(self, mode: Mode) -> None:
        """Enter ``mode`` with the setpoint it flies (hold/land/takeoff capture the pose now)."""
        v, st = self.v, self.status
        s = v.estimate
        n, e, d = s.position_ned_m
        yaw = s.attitude_rad[2]
        if mode is not Mode.AUTO_LOITER:
            st.failsafe_since_s = None
        if mode is Mode.AUTO_LAND:
            st.setpoint = Setpoint(position_ned_m=(n, e, NAN), velocity_ned_m_s=(0.0, 0.0, v.params.get("MPC_LAND_SPEED")),
                                   yaw_rad=yaw)
        elif mode is Mode.AUTO_PRECLAND:
            v.precland.start(yaw)
            st.setpoint = hold_setpoint(s)
        elif mode is Mode.AUTO_TAKEOFF:
            ground_d = -v.world.surface_height_m(n, e, s.time_s)
            st.setpoint = Setpoint(position_ned_m=(n, e, ground_d - self.takeoff_alt_m), velocity_ned_m_s=(0.0, 0.0, NAN),
                                   yaw_rad=yaw)
        elif mode in (Mode.AUTO_LOITER, Mode.POSCTL):
            st.setpoint = hold_setpoint(s)
        st.mode = mode

    def progress(self, state: VehicleState) -> None:
        """Per step: AUTO.TAKEOFF at its height holds there (AUTO.LOITER), as PX4's navigator."""
        st = self.status
        if st.mode is Mode.AUTO_TAKEOFF and not math.isnan(st.setpoint.position_ned_m[2]):
            if abs(state.position_ned_m[2] - st.setpoint.position_ned_m[2]) < TAKEOFF_REACHED_M:
                self.v.say(mavlink.MAV_SEVERITY_INFO, "Takeoff complete, holding")
                target = st.setpoint
                self.enter(Mode.AUTO_LOITER)
                st.setpoint = Setpoint(position_ned_m=target.position_ned_m, velocity_ned_m_s=(0.0, 0.0, 0.0),
                                       yaw_rad=target.yaw_rad)

    # ----- arming ------------------------------------------------------------------------
    def arm(self, force: bool = False) -> Result:
        v, st = self.v, self.status
        if st.armed:
            return mavlink.MAV_RESULT_ACCEPTED, ""
        st.armed = True
        st.armed_at_s = v.time_s
        st.touchdown = None
        v.controller.reset()
        st.setpoint = hold_setpoint(v.estimate) if st.mode is not Mode.OFFBOARD else st.setpoint
        v.say(mavlink.MAV_SEVERITY_INFO, "Armed")
        return mavlink.MAV_RESULT_ACCEPTED, ""

    def disarm(self, force: bool = False) -> Result:
        st = self.status
        if not st.armed:
            return mavlink.MAV_RESULT_ACCEPTED, ""
        if not st.landed and not force:
            return mavlink.MAV_RESULT_DENIED, "Disarm refused: in the air (use force)"
        self.disarm_now("Disarmed")
        return mavlink.MAV_RESULT_ACCEPTED, ""

    def disarm_now(self, why: str) -> None:
        self.status.armed = False
        self.v.say(mavlink.MAV_SEVERITY_INFO, why)

    def auto_disarm(self, t_s: float) -> None:
        """Per step, after the land detector: disarm once landed (COM_DISARM_LAND; 0.5 s in the
        landing modes), or when armed on the ground without taking off (COM_DISARM_PRFLT)."""
        st = self.status
        if not st.armed or st.landed_since_s is None:
            return
        landed_for = t_s - st.landed_since_s
        # as PX4, the landed disarms need a flight since arming (a touchdown); armed on the ground,
        # only the preflight timeout disarms, whatever the mode
        if st.mode in (Mode.AUTO_LAND, Mode.AUTO_PRECLAND) and st.touchdown is not None and landed_for > LAND_DISARM_S:
            self.disarm_now("Landed, disarming")
        elif st.touchdown is not None and landed_for > self.v.params.get("COM_DISARM_LAND") > 0:
            self.disarm_now("Landed, disarming")
        elif st.touchdown is None and t_s - st.armed_at_s > PREFLIGHT_DISARM_S and st.mode is not Mode.AUTO_TAKEOFF:
            climb = st.setpoint.velocity_ned_m_s[2]
            if climb >= 0 or math.isnan(climb):
                self.disarm_now("Not taking off, disarming")

    # ----- commands ----------------------------------------------------------------------
    def takeoff(self, alt_amsl_m: float) -> Result:
        v = self.v
        if not self.status.armed:
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED, "Takeoff refused: arm first"
        rel = alt_amsl_m - v.dynamics.home_alt_m if math.isfinite(alt_amsl_m) else NAN
        self.takeoff_alt_m = rel if math.isfinite(rel) and 0.3 < rel < 100 else v.params.get("MIS_TAKEOFF_ALT")
        self.enter(Mode.AUTO_TAKEOFF)
        v.say(mavlink.MAV_SEVERITY_INFO, f"Taking off to {self.takeoff_alt_m:.1f} m")
        return mavlink.MAV_RESULT_ACCEPTED, ""

    def land(self) -> Result:
        if self.status.landed and not self.status.armed:
            return mavlink.MAV_RESULT_DENIED, "Land refused: already landed"
        self.enter(Mode.AUTO_LAND)
        self.v.say(mavlink.MAV_SEVERITY_INFO, "Landing")
        return mavlink.MAV_RESULT_ACCEPTED, ""

    def precision_land(self) -> Result:
        """Personality: PX4's VEHICLE_CMD_NAV_PRECLAND (MAVLink command 23): AUTO.PRECLAND."""
        if self.status.landed and not self.status.armed:
            return mavlink.MAV_RESULT_DENIED, "Precision landing denied: landed"
        return self.request_mode(Mode.AUTO_PRECLAND)

    def reboot(self, what: float) -> Result:
        """Personality: MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN (the PX4 personality does not reboot)."""
        return mavlink.MAV_RESULT_UNSUPPORTED, ""

    def rebooting(self) -> bool:
        """Personality: True while the autopilot reboots (it sends nothing and reads nothing)."""
        return False

    def rebase_clock(self, shift_s: float) -> None:
        """Personality: the simulation clock went back ``shift_s`` at an episode reset; the times
        kept across episodes (a reboot's, a pre-arm timer's) move with it. PX4's: none."""
