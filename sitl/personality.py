"""The SITL's ArduCopter personality: the same JSBSim vehicle and cascade, seen from outside as
ArduCopter (``col-sitl --autopilot ardupilot``).

What changes, after ArduPilot's public documentation (Copter flight modes, "Copter Commands in
Guided Mode", the parameter list): the HEARTBEAT (MAV_AUTOPILOT_ARDUPILOTMEGA, custom_mode =
the Copter mode number); the modes STABILIZE 0, GUIDED 4, LOITER 5, RTL 6, LAND 9, BRAKE 17;
GUIDED, entered at any time, flies SET_POSITION_TARGET_LOCAL_NED and is where NAV_TAKEOFF works
(param7: metres above home); a velocity target not renewed within GUID_TIMEOUT stops the vehicle,
which stays in GUIDED; arming is refused while the EKF settles after boot, with "PreArm:"
reasons in STATUSTEXT; ArduCopter's parameter names for the limits and gains the cascade uses;
only HEARTBEAT and SYS_STATUS until streams are asked for (again after a reboot, which is
REBOOT_S of silence); no SYSTEM_TIME frame marker, so no lockstep. STABILIZE and LOITER fly as the SITL's position-assisted mode (centred sticks hold).
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sitl.ardupilot_plnd import (
    INT16_PARAMS,
    PLND_DEFAULTS,
    REAL_PARAMS,
    ApPrecLand,
    ApTargetEstimator,
)
from sitl.commander import Commander, Result
from sitl.config import SitlConfig
from sitl.control import Setpoint
from sitl.dynamics import VehicleState
from sitl.failsafe import Failsafe
from sitl.landing_target import TargetMeasurement
from sitl.modes import Mode
from sitl.offboard import (
    FRAME_BODY_NED,
    FRAME_BODY_OFFSET_NED,
    FRAME_LOCAL_NED,
    FRAME_LOCAL_OFFSET_NED,
    IGNORE_AX,
    IGNORE_AY,
    IGNORE_AZ,
    IGNORE_VX,
    IGNORE_VY,
    IGNORE_VZ,
    IGNORE_X,
    IGNORE_Y,
    IGNORE_YAW,
    IGNORE_YAW_RATE,
    IGNORE_Z,
    SetpointRejected,
    TargetFields,
)
from sitl.params import (
    BINDING_BY_NAME,
    REAL32,
    Param,
    ParamStore,
    apply_to_config,
    autopilot_params,
)
from sitl.precision_landing import PrecisionLanding
from sitl.setpoints import SetpointStreams
from sitl.status import hold_setpoint
from sitl.vehicle import SimVehicle

M = mavlink
NAN = math.nan
POS_IGNORE = IGNORE_X | IGNORE_Y | IGNORE_Z
VEL_IGNORE = IGNORE_VX | IGNORE_VY | IGNORE_VZ
ACC_IGNORE = IGNORE_AX | IGNORE_AY | IGNORE_AZ
COPTER_FRAMES = (FRAME_LOCAL_NED, FRAME_LOCAL_OFFSET_NED, FRAME_BODY_NED, FRAME_BODY_OFFSET_NED)
LOOK_AHEAD_MIN_SPEED_M_S = 1.0  # auto yaw faces the direction of travel above this speed
PREARM_REPORT_S = 30.0  # ArduPilot repeats failing pre-arm checks this often while disarmed
PREARM_REASONS = ("PreArm: EKF3 waiting for GPS config data", "Arm: Need Position Estimate")
RTL_ARRIVED_M = 0.5
REBOOT_S = 8.0  # silent after MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN (a real ArduCopter: seconds; longer than 1 Hz HEARTBEATs)


class CopterMode(IntEnum):
    """ArduCopter's mode numbers (HEARTBEAT custom_mode, DO_SET_MODE param2)."""

    STABILIZE = 0
    GUIDED = 4
    LOITER = 5
    RTL = 6
    LAND = 9
    BRAKE = 17


INTERNAL = {
    CopterMode.STABILIZE: Mode.POSCTL,
    CopterMode.GUIDED: Mode.OFFBOARD,
    CopterMode.LOITER: Mode.POSCTL,
    CopterMode.RTL: Mode.AUTO_LOITER,
    CopterMode.LAND: Mode.AUTO_LAND,
    CopterMode.BRAKE: Mode.AUTO_LOITER,
}
ARMABLE = (CopterMode.STABILIZE, CopterMode.GUIDED, CopterMode.LOITER)

# ArduCopter name -> (the SITL's PX4-named parameter it stands for, ArduCopter units per PX4 unit)
ALIASES: dict[str, tuple[str, float]] = {
    "WPNAV_SPEED": ("MPC_XY_VEL_MAX", 100.0),  # cm/s
    "WPNAV_SPEED_UP": ("MPC_Z_VEL_MAX_UP", 100.0),
    "WPNAV_SPEED_DN": ("MPC_Z_VEL_MAX_DN", 100.0),
    "ANGLE_MAX": ("MPC_TILTMAX_AIR", 100.0),  # centidegrees
    "PILOT_Y_RATE": ("MPC_MAN_Y_MAX", 1.0),  # deg/s
    "LAND_SPEED": ("MPC_LAND_SPEED", 100.0),
    "PILOT_TKOFF_ALT": ("MIS_TAKEOFF_ALT", 100.0),  # cm
    "DISARM_DELAY": ("COM_DISARM_LAND", 1.0),  # s
    "PSC_POSXY_P": ("MPC_XY_P", 1.0),
    "PSC_POSZ_P": ("MPC_Z_P", 1.0),
    "PSC_VELXY_P": ("MPC_XY_VEL_P_ACC", 1.0),
    "PSC_VELXY_I": ("MPC_XY_VEL_I_ACC", 1.0),
    "PSC_VELZ_P": ("MPC_Z_VEL_P_ACC", 1.0),
    "ATC_ANG_RLL_P": ("MC_ROLL_P", 1.0),
    "ATC_ANG_YAW_P": ("MC_YAW_P", 1.0),
    "ATC_RAT_RLL_P": ("MC_ROLLRATE_P", 1.0),
    "ATC_RAT_RLL_I": ("MC_ROLLRATE_I", 1.0),
    "ATC_RAT_RLL_D": ("MC_ROLLRATE_D", 1.0),
    "ATC_RAT_YAW_P": ("MC_YAWRATE_P", 1.0),
    "ATC_RAT_YAW_I": ("MC_YAWRATE_I", 1.0),
    "MOT_THST_HOVER": ("MPC_THR_HOVER", 1.0),
}
_BY_PX4 = {px4: (ap, scale) for ap, (px4, scale) in ALIASES.items()}


class CopterParams(ParamStore):
    """ArduCopter's names over MAVLink; the vehicle's own code still asks by PX4 name, which
    reads the aliased ArduCopter parameter (unit-converted) or, for what ArduCopter has no
    counterpart of, the PX4 default (not visible over MAVLink)."""

    def __init__(self, cfg: SitlConfig) -> None:
        hidden = ParamStore(autopilot_params(cfg.autopilot))
        params = []
        for ap, (px4, scale) in ALIASES.items():
            p = hidden.by_name(px4)
            assert p is not None
            params.append(Param(ap, p.value * scale, REAL32, p.minimum * scale, p.maximum * scale))
        params += [
            Param("GUID_TIMEOUT", cfg.personality.guid_timeout_s, REAL32, 0.1, 5.0),
            Param("SYSID_THISMAV", float(cfg.network.system_id), M.MAV_PARAM_TYPE_INT8, 1, 255),
            Param("FRAME_CLASS", 1.0, M.MAV_PARAM_TYPE_INT8, 0, 20),  # quad
            Param("FRAME_TYPE", 1.0, M.MAV_PARAM_TYPE_INT8, 0, 20),  # X
            Param("RNGFND1_TYPE", 0.0, M.MAV_PARAM_TYPE_INT8, 0, 100),  # none, as ArduCopter's SITL
        ] + plnd_params()
        params[[p.name for p in params].index("DISARM_DELAY")].value = 10.0
        super().__init__(params)
        self._hidden = hidden

    def get(self, name: str) -> float:
        if name in _BY_PX4:
            ap, scale = _BY_PX4[name]
            return super().get(ap) / scale
        if self.by_name(name) is not None:
            return super().get(name)
        return self._hidden.get(name)

    @staticmethod
    def binding_of(name: str) -> str | None:
        """The PX4 binding an ArduCopter parameter changes (None: not a cascade setting)."""
        px4 = ALIASES.get(name, ("", 1.0))[0]
        return px4 if px4 in BINDING_BY_NAME else None


def plnd_params() -> list[Param]:
    """AC_PrecLand's PLND_* parameters with ArduCopter's defaults (read live here; on ArduCopter
    PLND_TYPE takes effect after a reboot)."""
    def kind(name: str) -> int:
        if name in REAL_PARAMS:
            return REAL32
        return M.MAV_PARAM_TYPE_INT16 if name in INT16_PARAMS else M.MAV_PARAM_TYPE_INT8

    return [Param(name, float(value), kind(name)) for name, value in PLND_DEFAULTS.items()]


def copter_setpoint(f: TargetFields, position_ned_m: tuple[float, float, float], yaw_rad: float,
                    max_speed_m_s: float) -> Setpoint:
    """SET_POSITION_TARGET_LOCAL_NED as ArduCopter reads it: a position, velocity or acceleration
    group counts only when none of its bits is set; BODY_NED and BODY_OFFSET_NED turn velocity
    (forward, right, down) by the heading; positions are from the EKF origin in LOCAL_NED and
    BODY_NED, from the vehicle in LOCAL_OFFSET_NED and (turned by the heading) BODY_OFFSET_NED;
    yaw is relative only in BODY_OFFSET_NED; neither yaw nor yaw rate: face the travel."""
    if f.frame not in COPTER_FRAMES:
        raise SetpointRejected(f"coordinate frame {f.frame} not supported")
    use_pos, use_vel = not f.type_mask & POS_IGNORE, not f.type_mask & VEL_IGNORE
    if not f.type_mask & ACC_IGNORE:
        raise SetpointRejected("acceleration targets are not flown by the SITL")
    if not (use_pos or use_vel):
        raise SetpointRejected("no position or velocity: ArduCopter stops")
    values = [*(f.x, f.y, f.z) * use_pos, *(f.vx, f.vy, f.vz) * use_vel]
    if not all(math.isfinite(v) for v in values):
        raise SetpointRejected("non-finite value in a used field")
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    body = f.frame in (FRAME_BODY_NED, FRAME_BODY_OFFSET_NED)
    pos = (NAN, NAN, NAN)
    if use_pos:
        n, e = (c * f.x - s * f.y, s * f.x + c * f.y) if f.frame == FRAME_BODY_OFFSET_NED else (f.x, f.y)
        offset = f.frame in (FRAME_LOCAL_OFFSET_NED, FRAME_BODY_OFFSET_NED)
        base = position_ned_m if offset else (0.0, 0.0, 0.0)
        pos = (base[0] + n, base[1] + e, base[2] + f.z)
    vel = (NAN, NAN, NAN)
    if use_vel:
        vn, ve = (c * f.vx - s * f.vy, s * f.vx + c * f.vy) if body else (f.vx, f.vy)
        vel = tuple(max(-max_speed_m_s, min(max_speed_m_s, v)) for v in (vn, ve, f.vz))  # type: ignore[assignment]
    yaw, yaw_rate = NAN, NAN
    if not f.type_mask & IGNORE_YAW and math.isfinite(f.yaw):
        yaw = f.yaw + (yaw_rad if f.frame == FRAME_BODY_OFFSET_NED else 0.0)
    elif not f.type_mask & IGNORE_YAW_RATE and math.isfinite(f.yaw_rate):
        yaw_rate = f.yaw_rate
    elif use_vel and math.hypot(vel[0], vel[1]) > LOOK_AHEAD_MIN_SPEED_M_S:
        yaw = math.atan2(vel[1], vel[0])
    return Setpoint(position_ned_m=pos, velocity_ned_m_s=vel, yaw_rad=yaw, yaw_rate_rad_s=yaw_rate)


class CopterCommander(Commander):
    """ArduCopter's modes, arming checks, take-off, landing and reboot. Its mode number
    (:attr:`copter_mode`) picks the PX4-like mode that flies it (:data:`INTERNAL`)."""

    v: CopterVehicle

    def __init__(self, v: CopterVehicle) -> None:
        super().__init__(v)
        self.copter_mode = CopterMode.STABILIZE
        self.guided_velocity = False  # GUIDED flies a velocity target: GUID_TIMEOUT applies
        self.settle_s = v.cfg.personality.prearm_settle_s  # the EKF has settled from then on
        self.booting_until_s = -1.0
        self.next_prearm_report_s = 0.0

    def settling(self) -> bool:
        """The EKF is still settling after boot: no arming, no GUIDED."""
        return self.v.time_s < self.settle_s

    def rebooting(self) -> bool:
        """Silent for REBOOT_S after an accepted reboot, as ArduCopter is while it starts again."""
        return self.v.time_s < self.booting_until_s

    def rebase_clock(self, shift_s: float) -> None:
        """The reboot's and the pre-arm checks' times keep their age across an episode reset."""
        self.booting_until_s -= shift_s
        self.next_prearm_report_s -= shift_s
        self.settle_s -= shift_s

    # ----- modes -------------------------------------------------------------------------
    def set_mode_numbers(self, main: int, sub: int) -> Result:
        return self.request_copter_mode(main)

    def set_mode_custom(self, custom_mode: int) -> Result:
        return self.request_copter_mode(custom_mode)

    def request_copter_mode(self, number: int) -> Result:
        try:
            mode = CopterMode(number)
        except ValueError:
            return M.MAV_RESULT_FAILED, f"Mode change to {number} failed: not supported"
        if mode is CopterMode.GUIDED and self.settling():
            return M.MAV_RESULT_FAILED, "Mode change to GUIDED failed: requires position"
        self.enter_copter(mode)
        return M.MAV_RESULT_ACCEPTED, ""

    def enter_copter(self, mode: CopterMode) -> None:
        v, st = self.v, self.status
        self.copter_mode = mode
        st.failsafe_since_s = None
        if mode is CopterMode.GUIDED:  # starts by holding where it is
            st.mode = Mode.OFFBOARD
            st.setpoint = hold_setpoint(v.estimate)
            self.guided_velocity = False
        elif mode is CopterMode.LAND:
            self.enter(Mode.AUTO_LAND)
            v.precland.start(v.estimate.attitude_rad[2])
        elif mode is CopterMode.RTL:
            self.enter(Mode.AUTO_LOITER)
            home_n, home_e, _ = v.home_ned_m
            st.setpoint = Setpoint(position_ned_m=(home_n, home_e, v.estimate.position_ned_m[2]),
                                   velocity_ned_m_s=(0.0, 0.0, 0.0), yaw_rad=v.estimate.attitude_rad[2])
        else:
            self.enter(INTERNAL[mode])

    def progress(self, state: VehicleState) -> None:
        """Take-off done: GUIDED holds the altitude reached; RTL at home: lands."""
        super().progress(state)
        st = self.status
        if self.copter_mode is CopterMode.GUIDED and st.mode is Mode.AUTO_LOITER:
            st.mode = Mode.OFFBOARD
        if self.copter_mode is CopterMode.RTL and st.mode is Mode.AUTO_LOITER:
            n, e, _ = self.v.estimate.position_ned_m
            home = self.v.home_ned_m
            if math.hypot(n - home[0], e - home[1]) < RTL_ARRIVED_M:
                self.enter(Mode.AUTO_LAND)

    # ----- arming, take-off, land, reboot --------------------------------------------------
    def arm(self, force: bool = False) -> Result:
        if self.status.armed:
            return M.MAV_RESULT_ACCEPTED, ""
        if not force and self.settling():
            self.report_prearm()
            return M.MAV_RESULT_FAILED, ""
        if not force and self.copter_mode not in ARMABLE:
            return M.MAV_RESULT_FAILED, "Arm: Mode not armable"
        return super().arm(force)

    def report_prearm(self) -> None:
        for reason in PREARM_REASONS:
            self.v.say(M.MAV_SEVERITY_CRITICAL, reason)
        self.next_prearm_report_s = self.v.time_s + PREARM_REPORT_S

    def prearm_reports(self, t_s: float) -> None:
        """Disarmed while the EKF settles: the failing checks again every PREARM_REPORT_S."""
        if not self.status.armed and self.settling() and t_s >= self.next_prearm_report_s:
            self.report_prearm()

    def takeoff(self, alt_m: float) -> Result:
        """MAV_CMD_NAV_TAKEOFF: armed, in GUIDED, on the ground; param7 is metres above home.
        Refused silently otherwise (COMMAND_ACK FAILED), as ArduCopter does."""
        st = self.status
        if not st.armed or self.copter_mode is not CopterMode.GUIDED or not st.landed:
            return M.MAV_RESULT_FAILED, ""
        st.touchdown = None  # every flight's touchdown is judged, even without disarming between
        self.takeoff_alt_m = alt_m if math.isfinite(alt_m) and 0.3 < alt_m < 100 else self.v.params.get("MIS_TAKEOFF_ALT")
        self.enter(Mode.AUTO_TAKEOFF)
        return M.MAV_RESULT_ACCEPTED, ""

    def land(self) -> Result:
        """MAV_CMD_NAV_LAND: ArduCopter switches to LAND."""
        return self.request_copter_mode(CopterMode.LAND)

    def precision_land(self) -> Result:
        return M.MAV_RESULT_UNSUPPORTED, ""  # ArduCopter has no such command: LAND does it

    def reboot(self, what: float) -> Result:
        """MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN param1 = 1, disarmed: the parameters stay (they are
        in its eeprom), the boot-time ones take effect, the EKF settles again, STABILIZE."""
        if not (math.isfinite(what) and int(what) == 1):
            return M.MAV_RESULT_UNSUPPORTED, ""
        if self.status.armed:
            return M.MAV_RESULT_FAILED, "Reboot refused: disarm first"
        self.booting_until_s = self.v.time_s + REBOOT_S
        self.settle_s = self.booting_until_s + self.v.cfg.personality.prearm_settle_s
        self.v.precland.restart()
        self.enter_copter(CopterMode.STABILIZE)
        self.status.mode = Mode.POSCTL
        return M.MAV_RESULT_ACCEPTED, ""


class CopterFailsafe(Failsafe):
    """ArduCopter's: a velocity target not renewed within GUID_TIMEOUT stops the vehicle, which
    stays in GUIDED; landed in GUIDED it waits on the ground; and the pre-arm reports."""

    commander: CopterCommander

    def check(self, t_s: float) -> None:
        c, st = self.commander, self.status
        if c.copter_mode is CopterMode.GUIDED and st.mode is Mode.OFFBOARD and st.landed:
            st.setpoint = self._ground_idle()  # landed in GUIDED: targets wait for a take-off
            return
        if c.copter_mode is CopterMode.GUIDED and st.mode is Mode.OFFBOARD and c.guided_velocity:
            if t_s - st.last_offboard_s > self.v.params.get("GUID_TIMEOUT"):
                st.setpoint = hold_setpoint(self.v.estimate)  # stop, stay in GUIDED
                c.guided_velocity = False
        self._sticks_silent(t_s)
        c.prearm_reports(t_s)

    def _ground_idle(self) -> Setpoint:
        """On the ground, armed, waiting (ArduCopter's "safe ground handling"): push down."""
        s = self.v.estimate
        n, e, _ = s.position_ned_m
        return Setpoint(position_ned_m=(n, e, NAN), velocity_ned_m_s=(0.0, 0.0, self.v.params.get("MPC_LAND_SPEED")),
                        yaw_rad=s.attitude_rad[2])


class CopterSetpoints(SetpointStreams):
    """Targets as ArduCopter reads them (:func:`copter_setpoint`), flown only in GUIDED."""

    v: CopterVehicle

    def offboard(self, f: TargetFields) -> bool:
        v, st, c = self.v, self.status, self.v.commander
        s = v.estimate
        try:
            sp = copter_setpoint(f, s.position_ned_m, s.attitude_rad[2], v.params.get("MPC_XY_VEL_MAX"))
        except SetpointRejected as exc:
            self.refuse(exc)
            return False
        if c.copter_mode is not CopterMode.GUIDED:
            return False  # ArduCopter ignores targets outside GUIDED
        st.last_offboard_s = s.time_s
        st.latest_offboard_sp = sp
        c.guided_velocity = math.isnan(sp.position_ned_m[0])
        if st.mode is Mode.OFFBOARD and not st.landed:
            st.setpoint = sp
        return True


class ArduPilotPrecisionLanding(PrecisionLanding):
    """ArduCopter's (AC_PrecLand): in LAND, with PLND_ENABLED and the backend PLND_TYPE made at boot."""

    v: CopterVehicle

    def __init__(self, v: CopterVehicle) -> None:
        super().__init__(v)
        self.restart()

    def restart(self) -> None:
        """At boot: ArduCopter makes its precision landing backend from PLND_TYPE now, once (set
        later, it takes effect at the next reboot; PLND_ENABLED is read live)."""
        v = self.v
        self.estimator = ApTargetEstimator(v.param)
        self.plnd = ApPrecLand(v.param, rangefinder=False)
        self.backend = isinstance(v.params, CopterParams) and int(v.params.get("PLND_TYPE")) == 1

    def on(self) -> bool:
        return self.backend and int(self.v.params.get("PLND_ENABLED")) == 1

    def _rangefinder(self) -> bool:
        return int(self.v.params.get("RNGFND1_TYPE")) != 0

    def _in_land(self) -> bool:
        return self.v.commander.copter_mode is CopterMode.LAND

    def start(self, yaw_rad: float) -> None:
        self.plnd.start(self.pose())
        self.hold_yaw_rad = yaw_rad

    def measure(self, m: TargetMeasurement) -> bool:
        """Read only with PLND_ENABLED = 1 and PLND_TYPE = 1 (MAVLink); ignored otherwise."""
        if not self.on():
            return False
        height = self.pose().height_agl_m if self._rangefinder() else None
        used = self.estimator.measure(m, height)
        self._say_all(self.estimator.events)
        return used

    def run(self) -> None:
        """With precision landing on, the estimator keeps its inertial history every step; in
        LAND, the guidance replaces the vertical landing's setpoint."""
        if not self.on():
            return
        pose = self.pose()
        self.estimator.update(pose)
        self._say_all(self.estimator.events)
        if not self._in_land() or self.status.landed:
            return
        self.plnd.rangefinder = self._rangefinder()
        guidance = self.plnd.update(pose, self.estimator.estimate(pose), self.v.params.get("MPC_LAND_SPEED"))
        self._say_all(self.plnd.events)
        self.status.setpoint = self.guidance_setpoint(guidance)

    def phase(self) -> str | None:
        return self.plnd.state.value if self._in_land() and self.on() else None

    def _say_all(self, texts: list[str]) -> None:
        for text in texts:
            self.v.say(M.MAV_SEVERITY_INFO, text)
        texts.clear()


class CopterVehicle(SimVehicle):
    """The SITL vehicle as ArduCopter: GUIDED instead of OFFBOARD, BRAKE as hold, and the rest
    of the module's docstring. Internally it flies the PX4-like modes of :class:`SimVehicle`,
    with ArduCopter's parts in place of PX4's."""

    sends_frame_marker = False
    default_rates_hz = {M.MAVLINK_MSG_ID_HEARTBEAT: 1.0, M.MAVLINK_MSG_ID_SYS_STATUS: 1.0}
    commander: CopterCommander
    precland: ArduPilotPrecisionLanding

    def __init__(self, cfg: SitlConfig) -> None:
        super().__init__(cfg)
        self.params = CopterParams(cfg)
        self.controller.configure(apply_to_config(self.controller.cfg, self.params))

    def _new_commander(self) -> CopterCommander:
        return CopterCommander(self)

    def _new_failsafe(self) -> CopterFailsafe:
        return CopterFailsafe(self, self.commander)

    def _new_setpoints(self) -> CopterSetpoints:
        return CopterSetpoints(self)

    def _new_precland(self) -> ArduPilotPrecisionLanding:
        return ArduPilotPrecisionLanding(self)

    # ----- what the world sees -----------------------------------------------------------
    @property
    def copter_mode(self) -> CopterMode:
        return self.commander.copter_mode

    def request_copter_mode(self, number: int) -> Result:
        return self.commander.request_copter_mode(number)

    def heartbeat_mode(self) -> tuple[int, int]:
        return M.MAV_AUTOPILOT_ARDUPILOTMEGA, int(self.copter_mode)

    def land_rule(self) -> str:
        """ArduCopter's land detector works on the throttle at its lower limit, not on a commanded
        descent: the contact rule is the nearer one, whatever ``autopilot.land_detector`` says."""
        return "contact"

    def estimator_height_offset_m(self) -> float:
        """ArduCopter's EKF origin is home: heights read 0 on the ground there."""
        return 0.0

    def _enter_landed_disarmed(self) -> None:
        super()._enter_landed_disarmed()
        self.commander.copter_mode = CopterMode.STABILIZE
        self.status.mode = Mode.POSCTL

    def set_param(self, name: str, wire_value: float, kind: int | None = None) -> bool:
        if self.params.set(name, wire_value, kind) is None:
            return False
        if CopterParams.binding_of(name) is not None:
            self.controller.configure(apply_to_config(self.controller.cfg, self.params))
        return True

    # ----- simulator control surface ------------------------------------------------------
    def reset_episode(self, seed: int | None, start_s: float | None = None) -> np.ndarray:
        """As the PX4 personality: hovering at the start, armed, holding (here: BRAKE)."""
        start = super().reset_episode(seed, start_s)
        self.commander.copter_mode = CopterMode.BRAKE
        self.status.mode = Mode.AUTO_LOITER
        return start


def make_vehicle(cfg: SitlConfig) -> SimVehicle:
    """The vehicle with the configured personality."""
    return CopterVehicle(cfg) if cfg.personality.autopilot == "ardupilot" else SimVehicle(cfg)
