"""The simulated vehicle: JSBSim's dynamics and the cascade, flown by an autopilot of PX4's parts.

The parts are PX4's modules (docs/sitl.md "Code"): the commander (sitl/commander.py), the
failsafe (sitl/failsafe.py), the land detector (sitl/land_detector.py), the setpoint streams
(sitl/setpoints.py) and the precision landing (sitl/precision_landing.py). They share the
flight status (sitl/status.py); :class:`SimVehicle` builds them, runs them in a fixed order in
every FDM step, resets episodes, and is what the rest of the SITL talks to. Pure logic, no
sockets: the server feeds it decoded MAVLink messages and FDM steps, and sends what it returns.
Everything it does is a function of simulation time, so lockstep runs are deterministic.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sitl.commander import Commander, Result
from sitl.config import SitlConfig
from sitl.control import FlightController
from sitl.disturbance import EpisodeDisturbance
from sitl.dynamics import HOME_ALT_M, TURBULENCE_GROUND_ASL_M, Dynamics, VehicleState
from sitl.estimate_error import EstimateError
from sitl.failsafe import Failsafe
from sitl.land_detector import Px4LandDetector, VehicleLandDetector
from sitl.landing_target import TargetMeasurement
from sitl.modes import Mode
from sitl.offboard import TargetFields
from sitl.params import BINDING_BY_NAME, ParamStore, apply_to_config, autopilot_params
from sitl.precision_landing import PrecisionLanding, Px4PrecisionLanding
from sitl.setpoints import SetpointStreams
from sitl.status import FlightStatus, hold_setpoint
from sitl.world import Touchdown, World

FIRST_LOCKSTEP_EPISODE_S = 3.0
"""Simulation time of a lockstep run's first episode start. Until the companion's first reset
the lockstep SITL runs in real time (nobody answers its frames yet), so the time it has
reached depends on how long the companion took to start: about 2.1 s on an idle machine, over
a minute on a loaded one. The episode's physics depends on its start time in the last bits
(``start + k * dt`` rounds differently at 3 s and at 67 s), and those bits grow into other
landings; so the first episode starts here whatever came before, which is where an unhurried
start lands (the next whole second after 2.1 s), so that results made before the rule stand."""


class SimVehicle:
    """One multirotor with a PX4-like autopilot in a world with a pad on a ground vehicle.

    sitl/personality.py derives the ArduCopter-like one: it swaps parts and overrides the hooks
    marked "Personality".
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
        self.status = FlightStatus()
        self.land_detector = VehicleLandDetector(self.status, Px4LandDetector(cfg.autopilot), self.land_rule() == "px4",
                                                 self.world, self.controller, self.say, self._carried_velocity())
        self.height_offset_m = self.estimator_height_offset_m()
        self.params = ParamStore(autopilot_params(cfg.autopilot))
        self._loss_timeout_for_speed()
        self.rng = np.random.default_rng(cfg.world.seed)
        self.events: deque[tuple[int, str]] = deque(maxlen=64)
        self.episode = 0
        self.clock_offset_ms = 0
        """Boot clock minus simulation clock (whole seconds): see :meth:`reset_episode`."""
        self.commander = self._new_commander()
        self.failsafe = self._new_failsafe()
        self.setpoints = self._new_setpoints()
        self.precland = self._new_precland()
        spawn = (cfg.world.spawn_ne_m[0], cfg.world.spawn_ne_m[1], 0.0)
        self.home_ned_m = spawn
        self.dynamics.reset(spawn, yaw_rad=self.disturbance.yaw_rad)
        self._start_disturbance()
        self._enter_landed_disarmed()

    def _loss_timeout_for_speed(self) -> None:
        """COM_OF_LOSS_T times the speed factor when the clock runs faster or slower than real
        time, as PX4's SITL start script (rcS) sets it for ``PX4_SIM_SPEED_FACTOR``: a companion
        on the wall clock keeps OFFBOARD through the same pauses at any speed (real PX4 SIH at 2x
        failed safe 2 s into a gap, results/conformance/setpoint-gap.json). Lockstep is untouched."""
        clock = self.cfg.clock
        if clock.mode == "realtime" and clock.speed != 1.0:
            self.params.set("COM_OF_LOSS_T", self.cfg.autopilot.offboard_loss_hold_s * clock.speed)

    # ----- parts (a personality swaps them) -----------------------------------------------
    def _new_commander(self) -> Commander:
        return Commander(self)

    def _new_failsafe(self) -> Failsafe:
        return Failsafe(self, self.commander)

    def _new_setpoints(self) -> SetpointStreams:
        return SetpointStreams(self)

    def _new_precland(self) -> PrecisionLanding:
        """Personality: the precision landing it has (PX4's precland and target estimator)."""
        return Px4PrecisionLanding(self)

    def _new_dynamics(self) -> Dynamics:
        """A fresh JSBSim instance: its reset keeps internal state (a 0.2 mm drift after one
        episode), and a new one costs only a few milliseconds. It carries the episode's wind
        and turbulence (with turbulence JSBSim's ground sits at sea level: docs/sitl.md)."""
        d = self.disturbance
        ground_asl = TURBULENCE_GROUND_ASL_M if d.turbulence_w20_m_s > 0 else HOME_ALT_M
        dyn = Dynamics(self.cfg.clock.fdm_rate_hz, self.world.surface_height_m,
                       max_surface_height_m=self.world.roof_height_m, ground_asl_m=ground_asl,
                       carrier=self.world, carries=self.cfg.world.roof_carries)
        dyn.set_atmosphere(d.atmosphere())
        return dyn

    def _carried_velocity(self) -> Callable[[], tuple[float, float]] | None:
        """With ``roof_carries``, the velocity of the surface that carries the vehicle now, which
        touchdowns are judged relative to (a vehicle standing on the driving roof is still on it);
        None: the world's velocity, as before."""
        if not self.cfg.world.roof_carries:
            return None
        return lambda: self.dynamics.carried_velocity_ne_m_s

    def _start_disturbance(self) -> None:
        """Per-episode state of the disturbance: the camera's pose history (its latency), the
        autopilot's estimate error."""
        self.estimate_error = EstimateError(self.cfg.estimator, self.disturbance.seed, self.dynamics.dt_s)
        k = self.disturbance.latency_steps(self.cfg.clock.fdm_rate_hz)
        self._camera_history: deque[VehicleState] | None = deque([self.state], maxlen=k + 1) if k > 0 else None
        self._attitude_noise_step = -1
        self._attitude_noise = np.zeros(6)

    def param(self, name: str) -> float:
        """A parameter's value now (the precision landings read them live)."""
        return self.params.get(name)

    def _enter_landed_disarmed(self) -> None:
        self.status.landed_disarmed(hold_setpoint(self.estimate))
        self.controller.reset()
        self.land_detector.reset(landed=True)

    # ----- state -------------------------------------------------------------------------
    @property
    def state(self) -> VehicleState:
        return self.dynamics.state

    @property
    def estimate(self) -> VehicleState:
        """The state as the autopilot's estimator has it, which it flies on and reports: the
        truth, unless ``[sitl.estimator]`` sets an error (sitl/estimate_error.py)."""
        return self.estimate_error.estimate(self.dynamics.state)

    @property
    def mode(self) -> Mode:
        return self.status.mode

    @property
    def armed(self) -> bool:
        return self.status.armed

    @property
    def touchdown(self) -> Touchdown | None:
        return self.status.touchdown

    @property
    def landed(self) -> bool:
        return self.status.landed

    @property
    def landed_state(self) -> int:
        """EXTENDED_SYS_STATE's MAV_LANDED_STATE."""
        mode = self.status.mode
        if self.landed:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if mode is Mode.AUTO_TAKEOFF:
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        if mode is Mode.AUTO_LAND or (mode is Mode.AUTO_PRECLAND and self.precland.descending()):
            return mavlink.MAV_LANDED_STATE_LANDING
        return mavlink.MAV_LANDED_STATE_IN_AIR

    @property
    def rejected_setpoints(self) -> int:
        """Offboard targets refused so far (their warnings are said only now and then)."""
        return self.setpoints.rejected

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

    # ----- personality -------------------------------------------------------------------
    def heartbeat_mode(self) -> tuple[int, int]:
        """Personality: HEARTBEAT (autopilot, custom_mode)."""
        return mavlink.MAV_AUTOPILOT_PX4, self.status.mode.custom_mode

    def land_rule(self) -> str:
        """Personality: which land detector decides :attr:`landed` (docs/sitl.md "Land detector")."""
        return self.cfg.autopilot.land_detector

    def estimator_height_offset_m(self) -> float:
        """Personality: how far the reported local frame's origin is below the true one (PX4's
        estimator starts its origin where it started, not on the ground)."""
        return self.cfg.estimator.height_offset_m

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
        """Queue a STATUSTEXT (the server sends it)."""
        self.events.append((severity, text[:50]))

    # ----- simulation --------------------------------------------------------------------
    def step(self) -> VehicleState:
        """One FDM step: failsafes, mode progress, controller, dynamics, ground contact."""
        state, estimate = self.dynamics.state, self.estimate  # neither changes until the FDM steps
        self.failsafe.check(state.time_s)
        self.precland.run()
        self.commander.progress(estimate)
        new = self.dynamics.step(self._esc(state, estimate))
        self.estimate_error.advance()
        self.land_detector.update(new)
        self.commander.auto_disarm(new.time_s)
        if self._camera_history is not None:
            self._camera_history.append(new)
        return new

    def _esc(self, state: VehicleState, estimate: VehicleState) -> tuple[float, float, float, float]:
        """The controller's output, flown on the ``estimate`` (idle while landed, by the truth
        ``state``, and not asked to take off, by PX4's rule)."""
        st = self.status
        if self.land_detector.idles(state, st.setpoint, st.armed):
            return self.controller.idle(state)
        return self.controller.update(estimate, st.setpoint, st.armed)

    # ----- commands and messages: the parts' --------------------------------------------
    def arm(self, force: bool = False) -> Result:
        return self.commander.arm(force)

    def disarm(self, force: bool = False) -> Result:
        return self.commander.disarm(force)

    def request_mode(self, mode: Mode) -> Result:
        return self.commander.request_mode(mode)

    def set_mode_numbers(self, main: int, sub: int) -> Result:
        return self.commander.set_mode_numbers(main, sub)

    def set_mode_custom(self, custom_mode: int) -> Result:
        return self.commander.set_mode_custom(custom_mode)

    def takeoff(self, alt_m: float) -> Result:
        return self.commander.takeoff(alt_m)

    def land(self) -> Result:
        return self.commander.land()

    def precision_land(self) -> Result:
        return self.commander.precision_land()

    def reboot(self, what: float) -> Result:
        return self.commander.reboot(what)

    def rebooting(self) -> bool:
        return self.commander.rebooting()

    def offboard_setpoint(self, f: TargetFields) -> bool:
        return self.setpoints.offboard(f)

    def manual_control(self, x: float, y: float, z: float, r: float) -> None:
        self.setpoints.manual(x, y, z, r)

    def landing_target(self, m: TargetMeasurement) -> bool:
        return self.precland.measure(m)

    def refuse_target(self, why: str) -> None:
        self.precland.refuse_target(why)

    def precision_landing_state(self) -> str | None:
        return self.precland.phase()

    # ----- simulator control surface ------------------------------------------------------
    def _rebase_clock(self, next_whole_s: float, start_s: float) -> None:
        """The simulation clock jumps from ``next_whole_s`` to ``start_s``, the boot clock does
        not: the offset between them takes up the difference (whole seconds) and the times
        kept across episodes keep their age."""
        shift_s = next_whole_s - start_s
        if shift_s != int(shift_s):
            raise ValueError(f"an episode starts on a whole second of simulation time, got {start_s!r}")
        self.clock_offset_ms += int(shift_s) * 1000
        self.commander.rebase_clock(shift_s)

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
        self.land_detector.reset(landed=False)
        self.status.armed = True
        self.status.armed_at_s = t
        self.episode += 1
        self.say(mavlink.MAV_SEVERITY_INFO, f"Episode {self.episode} start")
        return start
