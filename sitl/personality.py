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
from sitl.config import SitlConfig
from sitl.control import Setpoint
from sitl.dynamics import VehicleState
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
from sitl.vehicle import SimVehicle, hold_setpoint

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


class CopterVehicle(SimVehicle):
    """The SITL vehicle as ArduCopter: GUIDED instead of OFFBOARD, BRAKE as hold, and the rest
    of the module's docstring. Internally it flies the PX4-like modes of :class:`SimVehicle`."""

    sends_frame_marker = False
    default_rates_hz = {M.MAVLINK_MSG_ID_HEARTBEAT: 1.0, M.MAVLINK_MSG_ID_SYS_STATUS: 1.0}

    CLOCK_STAMPS = ("_booting_until_s", "_next_prearm_report_s", "_settle_s")

    def __init__(self, cfg: SitlConfig) -> None:
        self.copter_mode = CopterMode.STABILIZE
        self._guided_velocity = False
        super().__init__(cfg)
        self.params = CopterParams(cfg)
        self.controller.configure(apply_to_config(self.controller.cfg, self.params))
        self._settle_s = cfg.personality.prearm_settle_s
        self._booting_until_s = -1.0
        self._next_prearm_report_s = 0.0

    # ----- what the world sees -----------------------------------------------------------
    def heartbeat_mode(self) -> tuple[int, int]:
        return M.MAV_AUTOPILOT_ARDUPILOTMEGA, int(self.copter_mode)

    def land_rule(self) -> str:
        """ArduCopter's land detector works on the throttle at its lower limit, not on a commanded
        descent: the contact rule is the nearer one, whatever ``autopilot.land_detector`` says."""
        return "contact"

    def estimator_height_offset_m(self) -> float:
        """ArduCopter's EKF origin is home: heights read 0 on the ground there."""
        return 0.0

    def settling(self) -> bool:
        """The EKF is still settling after boot: no arming, no GUIDED."""
        return self.time_s < self._settle_s

    # ----- modes -------------------------------------------------------------------------
    def set_mode_numbers(self, main: int, sub: int) -> tuple[int, str]:
        return self.request_copter_mode(main)

    def set_mode_custom(self, custom_mode: int) -> tuple[int, str]:
        return self.request_copter_mode(custom_mode)

    def request_copter_mode(self, number: int) -> tuple[int, str]:
        try:
            mode = CopterMode(number)
        except ValueError:
            return M.MAV_RESULT_FAILED, f"Mode change to {number} failed: not supported"
        if mode is CopterMode.GUIDED and self.settling():
            return M.MAV_RESULT_FAILED, "Mode change to GUIDED failed: requires position"
        self._enter(mode)
        return M.MAV_RESULT_ACCEPTED, ""

    def _enter(self, mode: CopterMode) -> None:
        self.copter_mode = mode
        self._failsafe_since_s = None
        if mode is CopterMode.GUIDED:  # starts by holding where it is
            self.mode = Mode.OFFBOARD
            self._sp = hold_setpoint(self.state)
            self._guided_velocity = False
        elif mode is CopterMode.LAND:
            self._set_mode(Mode.AUTO_LAND)
            self.plnd.start(self.precland_pose())
            self._hold_yaw_rad = self.state.attitude_rad[2]
        elif mode is CopterMode.RTL:
            self._set_mode(Mode.AUTO_LOITER)
            home_n, home_e, _ = self.home_ned_m
            self._sp = Setpoint(position_ned_m=(home_n, home_e, self.state.position_ned_m[2]),
                                velocity_ned_m_s=(0.0, 0.0, 0.0), yaw_rad=self.state.attitude_rad[2])
        else:
            self._set_mode(INTERNAL[mode])

    def _enter_landed_disarmed(self) -> None:
        super()._enter_landed_disarmed()
        self.copter_mode = CopterMode.STABILIZE
        self.mode = Mode.POSCTL

    # ----- arming, take-off, land ----------------------------------------------------------
    def arm(self, force: bool = False) -> tuple[int, str]:
        if self.armed:
            return M.MAV_RESULT_ACCEPTED, ""
        if not force and self.settling():
            self._report_prearm()
            return M.MAV_RESULT_FAILED, ""
        if not force and self.copter_mode not in ARMABLE:
            return M.MAV_RESULT_FAILED, "Arm: Mode not armable"
        return super().arm(force)

    def _report_prearm(self) -> None:
        for reason in PREARM_REASONS:
            self.say(M.MAV_SEVERITY_CRITICAL, reason)
        self._next_prearm_report_s = self.time_s + PREARM_REPORT_S

    def takeoff(self, alt_m: float) -> tuple[int, str]:
        """MAV_CMD_NAV_TAKEOFF: armed, in GUIDED, on the ground; param7 is metres above home.
        Refused silently otherwise (COMMAND_ACK FAILED), as ArduCopter does."""
        if not self.armed or self.copter_mode is not CopterMode.GUIDED or not self.landed:
            return M.MAV_RESULT_FAILED, ""
        self.touchdown = None  # every flight's touchdown is judged, even without disarming between
        self._takeoff_alt_m = alt_m if math.isfinite(alt_m) and 0.3 < alt_m < 100 else self.params.get("MIS_TAKEOFF_ALT")
        self._set_mode(Mode.AUTO_TAKEOFF)
        return M.MAV_RESULT_ACCEPTED, ""

    def land(self) -> tuple[int, str]:
        """MAV_CMD_NAV_LAND: ArduCopter switches to LAND."""
        return self.request_copter_mode(CopterMode.LAND)

    # ----- precision landing (AC_PrecLand) -------------------------------------------------
    def _start_precland(self) -> None:
        """At boot: ArduCopter makes its precision landing backend from PLND_TYPE now, once (set
        later, it takes effect at the next reboot; PLND_ENABLED is read live)."""
        self.target_estimator = ApTargetEstimator(self._param)  # type: ignore[assignment]
        self.plnd = ApPrecLand(self._param, rangefinder=False)
        self._plnd_backend = isinstance(self.params, CopterParams) and int(self.params.get("PLND_TYPE")) == 1

    def _plnd_on(self) -> bool:
        return self._plnd_backend and int(self.params.get("PLND_ENABLED")) == 1

    def reboot(self, what: float) -> tuple[int, str]:
        """MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN param1 = 1, disarmed: the parameters stay (they are
        in its eeprom), the boot-time ones take effect, the EKF settles again, STABILIZE."""
        if not (math.isfinite(what) and int(what) == 1):
            return M.MAV_RESULT_UNSUPPORTED, ""
        if self.armed:
            return M.MAV_RESULT_FAILED, "Reboot refused: disarm first"
        self._booting_until_s = self.time_s + REBOOT_S
        self._settle_s = self._booting_until_s + self.cfg.personality.prearm_settle_s
        self._start_precland()
        self._enter(CopterMode.STABILIZE)
        self.mode = Mode.POSCTL
        return M.MAV_RESULT_ACCEPTED, ""

    def rebooting(self) -> bool:
        """Silent for REBOOT_S after an accepted reboot, as ArduCopter is while it starts again."""
        return self.time_s < self._booting_until_s

    def _rangefinder(self) -> bool:
        return int(self.params.get("RNGFND1_TYPE")) != 0

    def landing_target(self, m: TargetMeasurement) -> bool:
        """Read only with PLND_ENABLED = 1 and PLND_TYPE = 1 (MAVLink); ignored otherwise."""
        if not self._plnd_on():
            return False
        estimator: ApTargetEstimator = self.target_estimator  # type: ignore[assignment]
        height = self.precland_pose().height_agl_m if self._rangefinder() else None
        used = estimator.measure(m, height)
        self._say_all(estimator.events)
        return used

    def precision_land(self) -> tuple[int, str]:
        return M.MAV_RESULT_UNSUPPORTED, ""  # ArduCopter has no such command: LAND does it

    def precision_landing_state(self) -> str | None:
        return self.plnd.state.value if self.copter_mode is CopterMode.LAND and self._plnd_on() else None

    def _say_all(self, texts: list[str]) -> None:
        for text in texts:
            self.say(M.MAV_SEVERITY_INFO, text)
        texts.clear()

    def _run_precland(self) -> None:
        """With precision landing on, the estimator keeps its inertial history every step; in
        LAND, the guidance replaces the vertical landing's setpoint."""
        if not self._plnd_on():
            return
        estimator: ApTargetEstimator = self.target_estimator  # type: ignore[assignment]
        pose = self.precland_pose()
        estimator.update(pose)
        self._say_all(estimator.events)
        if self.copter_mode is not CopterMode.LAND or self.landed:
            return
        self.plnd.rangefinder = self._rangefinder()
        guidance = self.plnd.update(pose, estimator.estimate(pose), self.params.get("MPC_LAND_SPEED"))
        self._say_all(self.plnd.events)
        self._sp = self._guidance_setpoint(guidance)

    # ----- setpoints and failsafes ---------------------------------------------------------
    def offboard_setpoint(self, f: TargetFields) -> bool:
        s = self.state
        try:
            sp = copter_setpoint(f, s.position_ned_m, s.attitude_rad[2], self.params.get("MPC_XY_VEL_MAX"))
        except SetpointRejected as exc:
            self.rejected_setpoints += 1
            if self.rejected_setpoints in (1, 10, 100) or self.rejected_setpoints % 1000 == 0:
                self.say(M.MAV_SEVERITY_WARNING, f"Setpoint refused ({self.rejected_setpoints}): {exc}")
            return False
        if self.copter_mode is not CopterMode.GUIDED:
            return False  # ArduCopter ignores targets outside GUIDED
        self._last_offboard_s = s.time_s
        self._latest_offboard_sp = sp
        self._guided_velocity = math.isnan(sp.position_ned_m[0])
        if self.mode is Mode.OFFBOARD and not self.landed:
            self._sp = sp
        return True

    def _check_failsafes(self, t_s: float) -> None:
        if self.copter_mode is CopterMode.GUIDED and self.mode is Mode.OFFBOARD and self.landed:
            self._sp = self._ground_idle()  # landed in GUIDED: targets wait for a take-off
            return
        if self.copter_mode is CopterMode.GUIDED and self.mode is Mode.OFFBOARD and self._guided_velocity:
            if t_s - self._last_offboard_s > self.params.get("GUID_TIMEOUT"):
                self._sp = hold_setpoint(self.state)  # stop, stay in GUIDED
                self._guided_velocity = False
        if self.mode is Mode.POSCTL and t_s - self._manual_at_s > 0.5 and not self._sp_is_hold():
            self._sp = hold_setpoint(self.state)
        if not self.armed and self.settling() and t_s >= self._next_prearm_report_s:
            self._report_prearm()

    def _ground_idle(self) -> Setpoint:
        """On the ground, armed, waiting (ArduCopter's "safe ground handling"): push down."""
        n, e, _ = self.state.position_ned_m
        return Setpoint(position_ned_m=(n, e, NAN), velocity_ned_m_s=(0.0, 0.0, self.params.get("MPC_LAND_SPEED")),
                        yaw_rad=self.state.attitude_rad[2])

    def _progress_mode(self, state: VehicleState) -> None:
        super()._progress_mode(state)
        if self.copter_mode is CopterMode.GUIDED and self.mode is Mode.AUTO_LOITER:
            self.mode = Mode.OFFBOARD  # take-off done: GUIDED holds the altitude reached
        if self.copter_mode is CopterMode.RTL and self.mode is Mode.AUTO_LOITER:
            n, e, _ = self.state.position_ned_m
            if math.hypot(n - self.home_ned_m[0], e - self.home_ned_m[1]) < RTL_ARRIVED_M:
                self._set_mode(Mode.AUTO_LAND)

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
        self.copter_mode = CopterMode.BRAKE
        self.mode = Mode.AUTO_LOITER
        return start


def make_vehicle(cfg: SitlConfig) -> SimVehicle:
    """The vehicle with the configured personality."""
    return CopterVehicle(cfg) if cfg.personality.autopilot == "ardupilot" else SimVehicle(cfg)
