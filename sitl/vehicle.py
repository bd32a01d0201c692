"""The simulated autopilot: modes, arming, commands, setpoints, failsafes and ground contact.

Pure logic over the dynamics and the controller, no sockets: the server feeds it decoded
MAVLink messages and FDM steps, and sends what it returns. Everything it does is a function of
simulation time, so lockstep runs are deterministic.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sitl.config import SitlConfig
from sitl.control import FlightController, Setpoint, wants_takeoff
from sitl.disturbance import EpisodeDisturbance
from sitl.dynamics import HOME_ALT_M, TURBULENCE_GROUND_ASL_M, Dynamics, VehicleState
from sitl.land_detector import Px4LandDetector
from sitl.landing_target import LandingTargetRejected, TargetMeasurement
from sitl.modes import Mode, refusal
from sitl.offboard import SetpointRejected, TargetFields, from_reported_frame, to_setpoint
from sitl.params import BINDING_BY_NAME, ParamStore, apply_to_config, autopilot_params
from sitl.px4_precland import (
    Guidance,
    PrecLandMode,
    Px4PrecLand,
    Px4State,
    Px4TargetEstimator,
    VehiclePose,
)
from sitl.world import Touchdown, World

NAN = math.nan
AUTOPILOT = 1
CAMERA = mavlink.MAV_COMP_ID_CAMERA
FORCE_DISARM_MAGIC = 21196
LANDED_SPEED_M_S = 0.5
PREFLIGHT_DISARM_S = 10.0
FIRST_LOCKSTEP_EPISODE_S = 3.0
"""Simulation time of a lockstep run's first episode start. Until the companion's first reset
the lockstep SITL runs in real time (nobody answers its frames yet), so the time it has
reached depends on how long the companion took to start: about 2.1 s on an idle machine, over
a minute on a loaded one. The episode's physics depends on its start time in the last bits
(``start + k * dt`` rounds differently at 3 s and at 67 s), and those bits grow into other
landings; so the first episode starts here whatever came before, which is where an unhurried
start lands (the next whole second after 2.1 s), so that results made before the rule stand."""


@dataclass(frozen=True)
class Outgoing:
    """A message to send: from which of our components, and to whom."""

    component: int
    message: mavlink.MAVLink_message
    to_sender_only: bool = True


def hold_setpoint(state: VehicleState) -> Setpoint:
    n, e, d = state.position_ned_m
    return Setpoint(position_ned_m=(n, e, d), velocity_ned_m_s=(0.0, 0.0, 0.0), yaw_rad=state.attitude_rad[2])


class SimVehicle:
    """One multirotor with a PX4-like autopilot in a world with a pad on a ground vehicle.

    sitl/personality.py derives the ArduCopter-like one; the hooks it overrides are marked.
    """

    sends_frame_marker = True  # personality: SYSTEM_TIME ends every frame (lockstep)
    default_rates_hz: dict[int, float] | None = None  # personality: None = PX4's streams

    def __init__(self, cfg: SitlConfig) -> None:
        self.cfg = cfg
        self.world = World(cfg.world)
        # boot counts as episode 0 of the run's sequence: disturbed like any episode
        self.disturbance = EpisodeDisturbance.draw(cfg.disturbance, (cfg.world.seed, 0))
        self.world.restart(0.0, self.disturbance.vehicle_velocity_ne_m_s)
        self.dynamics = self._new_dynamics()
        self.controller = FlightController(cfg.autopilot, self.dynamics.dt_s)
        self.land_detector = Px4LandDetector(cfg.autopilot)
        self._px4_landing = self.land_rule() == "px4"
        self.height_offset_m = self.estimator_height_offset_m()
        self.params = ParamStore(autopilot_params(cfg.autopilot))
        self.rng = np.random.default_rng(cfg.world.seed)
        self.events: deque[tuple[int, str]] = deque(maxlen=64)
        self.rejected_setpoints = 0
        self.rejected_targets = 0
        self.episode = 0
        self.clock_offset_ms = 0
        """Boot clock minus simulation clock (whole seconds): see :meth:`reset_episode`."""
        self._start_precland()
        spawn = (cfg.world.spawn_ne_m[0], cfg.world.spawn_ne_m[1], 0.0)
        self.home_ned_m = spawn
        self.dynamics.reset(spawn, yaw_rad=self.disturbance.yaw_rad)
        self._start_disturbance()
        self._enter_landed_disarmed()

    def _new_dynamics(self) -> Dynamics:
        """A fresh JSBSim instance: its reset keeps internal state (a 0.2 mm drift after one
        episode), and a new one costs only a few milliseconds. It carries the episode's wind
        and turbulence (with turbulence JSBSim's ground sits at sea level: docs/sitl.md)."""
        d = self.disturbance
        ground_asl = TURBULENCE_GROUND_ASL_M if d.turbulence_w20_m_s > 0 else HOME_ALT_M
        dyn = Dynamics(self.cfg.clock.fdm_rate_hz, self.world.surface_height_m,
                       max_surface_height_m=self.world.roof_height_m, ground_asl_m=ground_asl)
        dyn.set_atmosphere(d.atmosphere())
        return dyn

    def _start_disturbance(self) -> None:
        """Per-episode state of the disturbance: the camera's pose history (its latency)."""
        k = self.disturbance.latency_steps(self.cfg.clock.fdm_rate_hz)
        self._camera_history: deque[VehicleState] | None = deque([self.state], maxlen=k + 1) if k > 0 else None
        self._attitude_noise_step = -1
        self._attitude_noise = np.zeros(6)

    def _start_precland(self) -> None:
        """Personality: the precision landing it has (PX4's precland and target estimator)."""
        self.target_estimator = Px4TargetEstimator(self._param)
        self.precland = Px4PrecLand(self._param)

    def _param(self, name: str) -> float:
        return self.params.get(name)

    # ----- state -------------------------------------------------------------------------
    def _enter_landed_disarmed(self) -> None:
        self.mode = Mode.AUTO_LOITER
        self.armed = False
        self.touchdown: Touchdown | None = None
        self._sp = hold_setpoint(self.dynamics.state)
        self._last_offboard_s = -math.inf
        self._latest_offboard_sp: Setpoint | None = None
        self._failsafe_since_s: float | None = None
        self._landed_since_s: float | None = 0.0
        self._armed_at_s = -math.inf
        self._airborne = False
        self._manual_at_s = -math.inf
        self._last_down_speed_m_s = 0.0
        self.controller.reset()
        self.land_detector.reset(landed=True)

    @property
    def state(self) -> VehicleState:
        return self.dynamics.state

    @property
    def camera_state(self) -> VehicleState:
        """The pose the camera shows now: the state ``frame_latency`` ago (the episode's start
        state until that much of the episode has passed)."""
        history = self._camera_history
        return self.state if history is None else history[0]

    def reported_attitude(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Roll, pitch, yaw and body rates as the autopilot reports them (with the episode's
        noise, a function of the FDM step; yaw stays in (-pi, pi])."""
        s = self.state
        d = self.disturbance
        if not d.noisy_attitude:
            return s.attitude_rad, s.rates_frd_rad_s
        step = self.dynamics.steps
        if step != self._attitude_noise_step:
            self._attitude_noise_step, self._attitude_noise = step, d.attitude_noise(step)
        n = self._attitude_noise
        roll, pitch, yaw = (a + float(x) for a, x in zip(s.attitude_rad, n[:3]))
        yaw = math.pi - (math.pi - yaw) % (2 * math.pi)
        p, q, r = (w + float(x) for w, x in zip(s.rates_frd_rad_s, n[3:]))
        return (roll, pitch, yaw), (p, q, r)

    @property
    def time_s(self) -> float:
        return self.dynamics.state.time_s

    @property
    def time_boot_ms(self) -> int:
        return self.boot_ms(self.dynamics.state.time_s)

    def boot_ms(self, time_s: float) -> int:
        """The boot clock at simulation time ``time_s``: the simulation's, a whole number of
        seconds apart after :meth:`reset_episode` with ``start_s`` (the same integer otherwise)."""
        return int(round(time_s * 1000.0)) + self.clock_offset_ms

    @property
    def time_usec(self) -> int:
        """The boot clock in microseconds (GPS_RAW_INT, HOME_POSITION, SYSTEM_TIME)."""
        return int(self.dynamics.state.time_s * 1e6) + 1000 * self.clock_offset_ms

    @property
    def landed(self) -> bool:
        return self._landed_since_s is not None

    @property
    def landed_state(self) -> int:
        if self.landed:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if self.mode is Mode.AUTO_TAKEOFF:
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        if self.mode is Mode.AUTO_LAND or (self.mode is Mode.AUTO_PRECLAND and self._precland_descending()):
            return mavlink.MAV_LANDED_STATE_LANDING
        return mavlink.MAV_LANDED_STATE_IN_AIR

    def _precland_descending(self) -> bool:
        return self.precland.state in (Px4State.DESCEND_ABOVE_TARGET, Px4State.FINAL_APPROACH, Px4State.FALLBACK)

    def heartbeat_mode(self) -> tuple[int, int]:
        """Personality: HEARTBEAT (autopilot, custom_mode)."""
        return mavlink.MAV_AUTOPILOT_PX4, self.mode.custom_mode

    def land_rule(self) -> str:
        """Personality: which land detector decides :attr:`landed` (docs/sitl.md "Land detector")."""
        return self.cfg.autopilot.land_detector

    def estimator_height_offset_m(self) -> float:
        """Personality: how far the reported local frame's origin is below the true one (PX4's
        estimator starts its origin where it started, not on the ground)."""
        return self.cfg.estimator.height_offset_m

    def set_mode_numbers(self, main: int, sub: int) -> tuple[int, str]:
        """Personality: MAV_CMD_DO_SET_MODE's param2 and param3 (PX4: main and sub mode)."""
        try:
            mode = Mode.from_main_sub(main, sub)
        except ValueError as exc:
            return mavlink.MAV_RESULT_DENIED, str(exc)
        return self.request_mode(mode)

    def set_mode_custom(self, custom_mode: int) -> tuple[int, str]:
        """Personality: the SET_MODE message's custom_mode."""
        try:
            mode = Mode.from_custom_mode(custom_mode)
        except ValueError as exc:
            return mavlink.MAV_RESULT_DENIED, str(exc)
        return self.request_mode(mode)

    def setpoints_fresh(self) -> bool:
        return self.time_s - self._last_offboard_s <= self.params.get("COM_OF_LOSS_T")

    def set_param(self, name: str, wire_value: float, kind: int | None = None) -> bool:
        """PARAM_SET: store (clamped) and, for a limit or gain, fly with it from now on."""
        if self.params.set(name, wire_value, kind) is None:
            return False
        if name in BINDING_BY_NAME:
            cfg = apply_to_config(self.controller.cfg, self.params)
            self.controller.configure(cfg)
            self.land_detector.configure(cfg)
        return True

    def say(self, severity: int, text: str) -> None:
        self.events.append((severity, text[:50]))

    # ----- simulation --------------------------------------------------------------------
    def step(self) -> VehicleState:
        """One FDM step: failsafes, mode progress, controller, dynamics, ground contact."""
        state = self.dynamics.state
        self._check_failsafes(state.time_s)
        self._progress_mode(state)
        new = self.dynamics.step(self._esc(state))
        self._ground_contact(new)
        if self._camera_history is not None:
            self._camera_history.append(new)
        return new

    def _progress_mode(self, state: VehicleState) -> None:
        self._run_precland()
        if self.mode is Mode.AUTO_TAKEOFF and not math.isnan(self._sp.position_ned_m[2]):
            if abs(state.position_ned_m[2] - self._sp.position_ned_m[2]) < 0.15:
                self.say(mavlink.MAV_SEVERITY_INFO, "Takeoff complete, holding")
                target = self._sp
                self._set_mode(Mode.AUTO_LOITER)
                self._sp = Setpoint(position_ned_m=target.position_ned_m, velocity_ned_m_s=(0.0, 0.0, 0.0), yaw_rad=target.yaw_rad)

    def _esc(self, state: VehicleState) -> tuple[float, float, float, float]:
        """The controller's output; with PX4's land detector a landed vehicle idles until a
        setpoint asks it to take off (PX4's take-off handling)."""
        if self._px4_landing and self.armed and self.land_detector.landed and not wants_takeoff(state, self._sp):
            return self.controller.idle(state)
        return self.controller.update(state, self._sp, self.armed)

    def _ground_contact(self, s: VehicleState) -> None:
        """The touchdown (ground truth: the first settling contact after flight) and the landed
        state: that contact itself ("contact"), or PX4's land detector ("px4")."""
        contact_rule = not self._px4_landing
        vn, ve, vd = s.velocity_ned_m_s
        speed = math.sqrt(vn * vn + ve * ve + vd * vd)
        if s.on_ground and speed < LANDED_SPEED_M_S + 2.0 * abs(self._last_down_speed_m_s):
            if self._airborne and self.touchdown is None:
                td_speed = max(speed, self._last_down_speed_m_s)
                self.touchdown = self.world.judge(np.asarray(s.position_ned_m), td_speed, s.time_s)
                verdict = "on the pad" if self.touchdown.success else "off the pad"
                self.say(mavlink.MAV_SEVERITY_NOTICE, f"Touchdown {verdict}, {self.touchdown.distance_to_pad_m:.2f} m")
            self._airborne = False
            if contact_rule and self._landed_since_s is None:
                self._landed_since_s = s.time_s
        elif not s.on_ground:
            self._airborne = True
            if contact_rule:
                self._landed_since_s = None
        if not contact_rule:
            self._detect_landing(s)
        self._last_down_speed_m_s = vd
        self._auto_disarm(s.time_s)

    def _detect_landing(self, s: VehicleState) -> None:
        """PX4's land detector, fed the setpoint's commanded descent and the thrust asked for."""
        if not self.land_detector.update(s, self._sp.velocity_ned_m_s[2], self.controller.lift_ratio, self.armed):
            self._landed_since_s = None
        elif self._landed_since_s is None:
            self._landed_since_s = s.time_s

    def _auto_disarm(self, t_s: float) -> None:
        if not self.armed or self._landed_since_s is None:
            return
        landed_for = t_s - self._landed_since_s
        # as PX4, the landed disarms need a flight since arming (a touchdown); armed on the ground,
        # only the preflight timeout disarms, whatever the mode
        if self.mode in (Mode.AUTO_LAND, Mode.AUTO_PRECLAND) and self.touchdown is not None and landed_for > 0.5:
            self._disarm("Landed, disarming")
        elif self.touchdown is not None and landed_for > self.params.get("COM_DISARM_LAND") > 0:
            self._disarm("Landed, disarming")
        elif self.touchdown is None and t_s - self._armed_at_s > PREFLIGHT_DISARM_S and self.mode is not Mode.AUTO_TAKEOFF:
            if self._sp.velocity_ned_m_s[2] >= 0 or math.isnan(self._sp.velocity_ned_m_s[2]):
                self._disarm("Not taking off, disarming")

    def _check_failsafes(self, t_s: float) -> None:
        hold_s = self.params.get("COM_OF_LOSS_T")
        if self.mode is Mode.OFFBOARD and t_s - self._last_offboard_s > hold_s:
            self.say(mavlink.MAV_SEVERITY_WARNING, "Offboard setpoints lost: holding")
            self._set_mode(Mode.AUTO_LOITER)
            self._failsafe_since_s = t_s
        elif self._failsafe_since_s is not None and self.mode is Mode.AUTO_LOITER:
            if t_s - self._failsafe_since_s > self.params.get("COM_OBL_LAND_T") and not self.landed:
                self.say(mavlink.MAV_SEVERITY_WARNING, "Offboard still lost: landing")
                self._set_mode(Mode.AUTO_LAND)
        if self.mode is Mode.POSCTL and t_s - self._manual_at_s > 0.5 and not self._sp_is_hold():
            self._sp = hold_setpoint(self.state)

    def _sp_is_hold(self) -> bool:
        return self._sp.velocity_ned_m_s == (0.0, 0.0, 0.0) and not math.isnan(self._sp.position_ned_m[0])

    # ----- modes and arming --------------------------------------------------------------
    def _set_mode(self, mode: Mode) -> None:
        """Enter ``mode`` with the setpoint it flies (hold/land/takeoff capture the pose now)."""
        s = self.state
        n, e, d = s.position_ned_m
        yaw = s.attitude_rad[2]
        if mode is not Mode.AUTO_LOITER:
            self._failsafe_since_s = None
        if mode is Mode.AUTO_LAND:
            self._sp = Setpoint(position_ned_m=(n, e, NAN), velocity_ned_m_s=(0.0, 0.0, self.params.get("MPC_LAND_SPEED")), yaw_rad=yaw)
        elif mode is Mode.AUTO_PRECLAND:
            self.precland.start(self.precland_pose(), PrecLandMode.REQUIRED)
            self._hold_yaw_rad = yaw
            self._sp = hold_setpoint(s)
        elif mode is Mode.AUTO_TAKEOFF:
            ground_d = -self.world.surface_height_m(n, e, s.time_s)
            self._sp = Setpoint(position_ned_m=(n, e, ground_d - self._takeoff_alt_m), velocity_ned_m_s=(0.0, 0.0, NAN), yaw_rad=yaw)
        elif mode in (Mode.AUTO_LOITER, Mode.POSCTL):
            self._sp = hold_setpoint(s)
        self.mode = mode

    _takeoff_alt_m = 2.5

    def arm(self, force: bool = False) -> tuple[int, str]:
        if self.armed:
            return mavlink.MAV_RESULT_ACCEPTED, ""
        self.armed = True
        self._armed_at_s = self.time_s
        self.touchdown = None
        self.controller.reset()
        self._sp = hold_setpoint(self.state) if self.mode is not Mode.OFFBOARD else self._sp
        self.say(mavlink.MAV_SEVERITY_INFO, "Armed")
        return mavlink.MAV_RESULT_ACCEPTED, ""

    def disarm(self, force: bool = False) -> tuple[int, str]:
        if not self.armed:
            return mavlink.MAV_RESULT_ACCEPTED, ""
        if not self.landed and not force:
            return mavlink.MAV_RESULT_DENIED, "Disarm refused: in the air (use force)"
        self._disarm("Disarmed")
        return mavlink.MAV_RESULT_ACCEPTED, ""

    def _disarm(self, why: str) -> None:
        self.armed = False
        self.say(mavlink.MAV_SEVERITY_INFO, why)

    def request_mode(self, mode: Mode) -> tuple[int, str]:
        why = refusal(mode, armed=self.armed, landed=self.landed, setpoints_fresh=self.setpoints_fresh())
        if why:
            return mavlink.MAV_RESULT_DENIED, why
        if mode is self.mode:
            return mavlink.MAV_RESULT_ACCEPTED, ""
        if mode is Mode.OFFBOARD:
            self.mode = mode
            self._sp = self._latest_offboard_sp or hold_setpoint(self.state)
            self._failsafe_since_s = None
        else:
            self._set_mode(Mode.POSCTL if mode in (Mode.MANUAL, Mode.ALTCTL) else mode)
        self.say(mavlink.MAV_SEVERITY_INFO, f"Mode {self.mode.px4_name}")
        return mavlink.MAV_RESULT_ACCEPTED, ""

    def takeoff(self, alt_amsl_m: float) -> tuple[int, str]:
        if not self.armed:
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED, "Takeoff refused: arm first"
        rel = alt_amsl_m - self.dynamics.home_alt_m if math.isfinite(alt_amsl_m) else NAN
        self._takeoff_alt_m = rel if math.isfinite(rel) and 0.3 < rel < 100 else self.params.get("MIS_TAKEOFF_ALT")
        self._set_mode(Mode.AUTO_TAKEOFF)
        self.say(mavlink.MAV_SEVERITY_INFO, f"Taking off to {self._takeoff_alt_m:.1f} m")
        return mavlink.MAV_RESULT_ACCEPTED, ""

    def land(self) -> tuple[int, str]:
        if self.landed and not self.armed:
            return mavlink.MAV_RESULT_DENIED, "Land refused: already landed"
        self._set_mode(Mode.AUTO_LAND)
        self.say(mavlink.MAV_SEVERITY_INFO, "Landing")
        return mavlink.MAV_RESULT_ACCEPTED, ""

    # ----- precision landing ---------------------------------------------------------------
    def precland_pose(self) -> VehiclePose:
        """The vehicle as its estimator reports it (the local frame of LOCAL_POSITION_NED), with
        the height above what is below it (a distance sensor)."""
        s = self.state
        n, e, d = s.position_ned_m
        height = -d - self.world.surface_height_m(n, e, s.time_s)
        return VehiclePose(s.time_s, (n, e, d - self.height_offset_m), s.velocity_ned_m_s, s.attitude_rad, height)

    def landing_target(self, m: TargetMeasurement) -> bool:
        """Personality: LANDING_TARGET; False (and a warning) when it is refused."""
        try:
            self.target_estimator.measure(m, self.precland_pose())
        except LandingTargetRejected as exc:
            self.refuse_target(str(exc))
            return False
        return True

    def refuse_target(self, why: str) -> None:
        """A refused LANDING_TARGET: counted, and said now and then (a stream of them must not
        flood STATUSTEXT)."""
        self.rejected_targets += 1
        if self.rejected_targets in (1, 10, 100) or self.rejected_targets % 1000 == 0:
            self.say(mavlink.MAV_SEVERITY_CRITICAL, why)

    def reboot(self, what: float) -> tuple[int, str]:
        """Personality: MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN (the PX4 personality does not reboot)."""
        return mavlink.MAV_RESULT_UNSUPPORTED, ""

    def rebooting(self) -> bool:
        """Personality: True while the autopilot reboots (it sends nothing and reads nothing)."""
        return False

    def precision_land(self) -> tuple[int, str]:
        """Personality: PX4's VEHICLE_CMD_NAV_PRECLAND (MAVLink command 23): AUTO.PRECLAND."""
        if self.landed and not self.armed:
            return mavlink.MAV_RESULT_DENIED, "Precision landing denied: landed"
        return self.request_mode(Mode.AUTO_PRECLAND)

    def precision_landing_state(self) -> str | None:
        """Personality: the precision landing's phase while one runs (ground truth for tests and
        experiments: PX4 logs it on its console only)."""
        return self.precland.state.value if self.mode is Mode.AUTO_PRECLAND else None

    def _run_precland(self) -> None:
        """The estimator runs while it has a target; the state machine only in AUTO.PRECLAND.
        (Nothing at all otherwise: this is in every FDM step of every experiment.)"""
        if self.mode is not Mode.AUTO_PRECLAND and not self.target_estimator.active:
            return
        pose = self.precland_pose()
        self.target_estimator.predict(pose)
        if self.mode is not Mode.AUTO_PRECLAND:
            return
        if self.landed and self.touchdown is not None:
            self.precland.landed(pose.time_s)
        guidance = self.precland.update(pose, *self.target_estimator.take())
        self.precland.events.clear()  # PX4 logs these on its console only, not as STATUSTEXT
        self._sp = self._guidance_setpoint(guidance)

    def _guidance_setpoint(self, g: Guidance) -> Setpoint:
        """A precision landing's guidance (in the reported frame) as a controller setpoint."""
        velocity_ff = (g.vn_m_s, g.ve_m_s)
        if g.down_m is None:
            down = g.descent_m_s if g.descent_m_s is not None else self.params.get("MPC_LAND_SPEED")
            return Setpoint(position_ned_m=(g.north_m, g.east_m, NAN), velocity_ned_m_s=(*velocity_ff, down),
                            yaw_rad=self._hold_yaw_rad)
        return Setpoint(position_ned_m=(g.north_m, g.east_m, g.down_m + self.height_offset_m),
                        velocity_ned_m_s=(*velocity_ff, 0.0), yaw_rad=self._hold_yaw_rad)

    _hold_yaw_rad = 0.0

    # ----- setpoint streams ----------------------------------------------------------------
    def offboard_setpoint(self, f: TargetFields) -> bool:
        """Apply SET_POSITION_TARGET_LOCAL_NED; False (and a warning) when it is refused."""
        s = self.state
        f = from_reported_frame(f, self.height_offset_m)
        try:
            sp = to_setpoint(f, s.position_ned_m, s.attitude_rad[2], self.params.get("MPC_XY_VEL_MAX"))
        except SetpointRejected as exc:
            self.rejected_setpoints += 1
            if self.rejected_setpoints in (1, 10, 100) or self.rejected_setpoints % 1000 == 0:
                self.say(mavlink.MAV_SEVERITY_WARNING, f"Setpoint refused ({self.rejected_setpoints}): {exc}")
            return False
        self._last_offboard_s = s.time_s
        self._latest_offboard_sp = sp
        if self.mode is Mode.OFFBOARD:
            self._sp = sp
        return True

    def manual_control(self, x: float, y: float, z: float, r: float) -> None:
        """MANUAL_CONTROL sticks fly the vehicle in POSCTL (PX4's position mode)."""
        self._manual_at_s = self.time_s
        if self.mode is not Mode.POSCTL:
            return
        sticks = [max(-1.0, min(1.0, v / 1000.0)) if math.isfinite(v) else 0.0 for v in (x, y, r)]
        thr = max(0.0, min(1.0, z / 1000.0)) if math.isfinite(z) else 0.5
        climb = (thr - 0.5) * 2.0
        if max(abs(v) for v in (*sticks, climb)) < 0.05:
            if not self._sp_is_hold():
                self._sp = hold_setpoint(self.state)
            return
        vxy = self.params.get("MPC_XY_VEL_MAX")
        yaw = self.state.attitude_rad[2]
        fwd, right = sticks[0] * vxy, sticks[1] * vxy
        c, s_ = math.cos(yaw), math.sin(yaw)
        vz = -climb * (self.params.get("MPC_Z_VEL_MAX_UP") if climb > 0 else self.params.get("MPC_Z_VEL_MAX_DN"))
        self._sp = Setpoint(
            velocity_ned_m_s=(c * fwd - s_ * right, s_ * fwd + c * right, vz),
            yaw_rate_rad_s=sticks[2] * math.radians(self.params.get("MPC_MAN_Y_MAX")),
        )

    # ----- simulator control surface ------------------------------------------------------
    CLOCK_STAMPS: tuple[str, ...] = ()
    """Simulation times the vehicle keeps across an episode reset (a personality's reboot and
    pre-arm timers); the stamps of flight (setpoints, failsafe, landing) start afresh anyway."""

    def _rebase_clock(self, next_whole_s: float, start_s: float) -> None:
        """The simulation clock jumps from ``next_whole_s`` to ``start_s``, the boot clock does
        not: the offset between them takes up the difference (whole seconds) and the stamps
        kept keep their age."""
        shift_s = next_whole_s - start_s
        if shift_s != int(shift_s):
            raise ValueError(f"an episode starts on a whole second of simulation time, got {start_s!r}")
        self.clock_offset_ms += int(shift_s) * 1000
        for name in self.CLOCK_STAMPS:
            stamp = getattr(self, name)
            if stamp is not None:
                setattr(self, name, stamp - shift_s)

    def reset_episode(self, seed: int | None, start_s: float | None = None) -> np.ndarray:
        """Place the vehicle at a random start above the pad, hovering, armed, in hold.

        ``start_s``: the episode starts at this simulation time whatever the time now (a
        lockstep run's first episode: :data:`FIRST_LOCKSTEP_EPISODE_S`); the boot clock goes on
        from where it was, to the next whole second, so nothing the world sees runs backwards.
        """
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        # the disturbance has its own stream: the starts are those of an undisturbed run
        self.disturbance = EpisodeDisturbance.draw(
            self.cfg.disturbance, seed if seed is not None else (self.cfg.world.seed, self.episode + 1)
        )
        # Episodes start on a whole second of simulation time: the frames' time_boot_ms (whole
        # milliseconds of a 95.238 ms period) then round alike in every episode, so whatever
        # uses them (a pilot's timers) does not depend on when the episode began.
        t = float(math.ceil(self.time_s))
        if start_s is not None:
            self._rebase_clock(t, float(start_s))
            t = float(start_s)
        self.world.restart(t, self.disturbance.vehicle_velocity_ne_m_s)
        start = self.world.episode_start(self.rng, t)
        self.dynamics = self._new_dynamics()
        self.dynamics.reset(tuple(start), yaw_rad=self.disturbance.yaw_rad, time_s=t)
        self._start_disturbance()
        self._enter_landed_disarmed()
        self._landed_since_s = None
        self.land_detector.reset(landed=False)
        self._airborne = True
        self.armed = True
        self._armed_at_s = t
        self.episode += 1
        self.say(mavlink.MAV_SEVERITY_INFO, f"Episode {self.episode} start")
        return start
