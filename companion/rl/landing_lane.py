"""One env of the batched landing env: its direct SITL and what ``LandingEnv``'s session keeps.

:class:`LandingLane` holds, for one env, what :class:`~companion.rl.gym_env.LandingEnv` keeps
across steps besides the vehicle: the session's home frame (heights for the geofence), the
episode's seed, step count and last good observation, and the episode start of
:meth:`EpisodeRunner.begin <companion.control.session.EpisodeRunner.begin>` on a lockstep SITL
with a control surface, step by step: reset; frames (answered with a zero setpoint) until the
vehicle reports being in the air after it; one zero setpoint and its frame; OFFBOARD (asked again
after five more frames if refused, three times); the whole start again, up to three times, on a
link error, as ``LandingEnv`` does. The per-step arithmetic (commands, setpoints, observation
vectors) is done for all lanes at once by :mod:`companion.rl.batched_env`.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from companion.commands import CommandMapper
from companion.config import CompanionConfig
from companion.control.episode_start import OFFBOARD_ATTEMPTS, RETRY_STREAM_FRAMES, TELEMETRY_FRAMES
from companion.control.safety import Geofence
from companion.errors import CommandRejected, ConfigError, LinkError
from companion.link.base import VehicleSnapshot
from companion.link.dialect import Dialect, dialect_for
from companion.link.home import HomeFrame
from companion.link.mavlink_link import result_name
from companion.rl.direct_sitl import DirectSitl
from companion.vision.observation import OBS_DIM
from sitl.config import SitlConfig

log = logging.getLogger(__name__)
START_ATTEMPTS = 3  # LandingEnv._start
ACCEPTED = 0  # MAV_RESULT_ACCEPTED


class LandingLane:
    """One env: its SITL, seeds, step count, home frame and last observation. The attributes a
    ``LandingEnv`` shows to a vec env's ``get_attr`` (``action_dims``, ``max_steps``, ...) are
    here too, and :meth:`ground_truth` as ``LandingEnv.ground_truth``."""

    render_mode = None

    def __init__(self, cfg: CompanionConfig, sitl_cfg: SitlConfig, action_dims: int, descent_throttle: float) -> None:
        self.cfg = cfg
        self.action_dims = action_dims
        self.descent_throttle = descent_throttle
        self.max_steps = cfg.session.max_steps
        self.sitl = DirectSitl(sitl_cfg, cfg.link)
        self.home = HomeFrame()
        self.mapper = CommandMapper(cfg.commands)  # repairs of this env's actions, counted and logged
        self.fence = Geofence.from_config(cfg.safety)
        self.next_seed = cfg.session.seed
        self.seed: int | None = None
        self.steps = 0
        self.last_obs = np.zeros(OBS_DIM, dtype=np.float32)
        self.ended_truth: dict[str, Any] | None = None
        """The ground truth when this env's last episode ended (a vec env starts the next one at
        once, so :meth:`ground_truth` shows that one): where the episode touched down."""
        self.dialect: Dialect = dialect_for(self.sitl.connect().autopilot)
        if not self.dialect.stream_before_offboard:
            raise ConfigError(f"the batched env flies PX4's OFFBOARD, not {self.dialect.name}")
        # LandingEnv flies the first start once, so that every later reset(seed) repeats
        self.begin(None)

    # ----- episode start ---------------------------------------------------------------------
    def begin(self, seed: int | None, attempts: int = START_ATTEMPTS) -> VehicleSnapshot:
        """Start an episode (``LandingEnv._start``): the first frame the agent observes.
        ``attempts=1`` starts as the session's ``EpisodeRunner.run`` does, without a retry."""
        for attempt in range(1, attempts + 1):
            try:
                return self._start(seed)
            except LinkError as exc:
                if attempt == attempts:
                    raise
                log.warning("episode start %s failed (%s); trying again", seed, exc)
        raise AssertionError("unreachable")

    def _start(self, seed: int | None) -> VehicleSnapshot:
        reply = self.sitl.reset(seed)
        snap = self._wait_in_air(int(reply["time_boot_ms"]))
        if not snap.armed:
            self._ask("arm", self.sitl.arm(), "")
        return self._enter_offboard()

    def _wait_in_air(self, after_ms: int) -> VehicleSnapshot:
        for _ in range(TELEMETRY_FRAMES):
            snap = self.next_frame()
            if snap.time_boot_ms > after_ms and snap.in_air:
                return snap
            self.hold()
        raise LinkError("the vehicle did not report being in the air after the reset")

    def _enter_offboard(self) -> VehicleSnapshot:
        """PX4: a fresh setpoint stream, then OFFBOARD; a refusal streams longer and asks again."""
        mode = self.dialect.offboard_mode
        for attempt in range(OFFBOARD_ATTEMPTS):
            for _ in range(1 if attempt == 0 else RETRY_STREAM_FRAMES):
                self.hold()
                snap = self.next_frame()
            try:
                self._ask(f"set_mode({mode!r})", self.sitl.request_mode(mode),
                          "OFFBOARD needs a setpoint stream first; AUTO modes need a position estimate")
                return snap
            except CommandRejected:
                if attempt == OFFBOARD_ATTEMPTS - 1:
                    raise
        raise AssertionError("unreachable")

    @staticmethod
    def _ask(command: str, answer: tuple[int, str], hint: str) -> None:
        """A command's result as the link reports it: CommandRejected unless accepted."""
        result, why = answer
        if result != ACCEPTED:
            raise CommandRejected(command, result_name(result), hint, reasons=(why,) if why else ())

    # ----- frames ------------------------------------------------------------------------------
    def next_frame(self) -> VehicleSnapshot:
        """The next lockstep frame's telemetry, as the session's ``_next_snapshot`` takes it."""
        snap = self.sitl.advance()
        assert snap is not None  # connected: the vehicle has been heard
        self.home.update(snap)
        return snap

    def hold(self) -> None:
        """The session's HOLD: a zero body velocity, sent as is (no limiter)."""
        self.velocity((0.0, 0.0, 0.0), 0.0)

    def velocity(self, forward_right_down_m_s: tuple[float, float, float], yaw_rate_rad_s: float) -> None:
        """A body-frame velocity setpoint, in the dialect's frame and type mask."""
        self.sitl.command_velocity(self.dialect.body_frame, self.dialect.body_type_mask, forward_right_down_m_s,
                                   yaw_rate_rad_s)

    # ----- truth -------------------------------------------------------------------------------
    def ground_truth(self) -> dict[str, Any]:
        """The SITL's truth (vehicle and pad NED, touchdown), as ``LandingEnv.ground_truth``."""
        return self.sitl.truth()
