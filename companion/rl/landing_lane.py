"""One lane of the batched drivers: a direct SITL and what ``LandingEnv``'s session keeps.

:class:`LandingLane` is the vehicle port of the batched episode core
(:class:`~companion.control.lanes.LanePort`) on the SITL's own vehicle, scheduler and renderer,
driven directly (:mod:`companion.rl.direct_sitl`), with the session's home frame, geofence and
episode start: the start of :class:`~companion.control.episode_start.EpisodeStart` (``LandingEnv``'s
lane, :class:`~companion.control.link_lane.LinkLane`) on a lockstep SITL with a control surface,
step by step: reset; frames (answered with a zero setpoint) until the vehicle reports being in the air after it; one zero setpoint and its frame;
OFFBOARD (asked again after five more frames if refused, three times); the whole start again, up
to three times, on a link error, as ``LandingEnv`` does. It also keeps what a ``LandingEnv``
shows a vec env's ``get_attr`` (its seeds, ``action_dims``, ``max_steps``, ...).
"""

from __future__ import annotations

import contextlib
from typing import Any

import numpy as np

from companion.commands import CommandMapper
from companion.config import CompanionConfig
from companion.control.episode_start import OFFBOARD_ATTEMPTS, RETRY_STREAM_FRAMES, TELEMETRY_FRAMES
from companion.control.lanes import ACCEPTED, START_ATTEMPTS, start_with_retries
from companion.control.safety import Geofence
from companion.errors import CommandRejected, ConfigError, LinkError
from companion.inprocess import one_opencv_thread
from companion.link.dialect import Dialect, dialect_for
from companion.link.home import HomeFrame
from companion.link.mavlink_link import result_name
from companion.msg.snapshot import VehicleSnapshot
from companion.rl.direct_sitl import DirectSitl
from sitl.config import SitlConfig


def open_lanes(cfg: CompanionConfig, sitl_cfg: SitlConfig, n: int, action_dims: int,
               descent_throttle: float) -> tuple[contextlib.ExitStack, list[LandingLane]]:
    """``n`` lanes, and the stack that gives OpenCV its threads back when closed (the lanes
    render on one thread, as the in-process SITL does)."""
    stack = contextlib.ExitStack()
    stack.enter_context(one_opencv_thread())
    try:
        return stack, [LandingLane(cfg, sitl_cfg, action_dims, descent_throttle) for _ in range(n)]
    except BaseException:
        stack.close()
        raise


class LandingLane:
    """One vehicle of the batched drivers (module docstring)."""

    render_mode = None

    def __init__(self, cfg: CompanionConfig, sitl_cfg: SitlConfig, action_dims: int, descent_throttle: float) -> None:
        self.cfg = cfg
        self.action_dims = action_dims
        self.descent_throttle = descent_throttle
        self.max_steps = cfg.session.max_steps
        self.sitl = DirectSitl(sitl_cfg, cfg.link)
        self.image_size_px = (self.sitl.cfg.camera.width_px, self.sitl.cfg.camera.height_px)
        self.home = HomeFrame()
        self.mapper = CommandMapper(cfg.commands)  # repairs of this env's actions, counted and logged
        self.fence = Geofence.from_config(cfg.safety)
        self.next_seed = cfg.session.seed
        self.seed: int | None = None
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
        return start_with_retries(self._start, seed, attempts)

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

    def request_hold_mode(self) -> tuple[int, str]:
        """The dialect's hold mode, as the session asks it when the vehicle leaves the fence."""
        return self.sitl.request_mode(self.dialect.hold_mode)

    def velocity(self, forward_right_down_m_s: tuple[float, float, float], yaw_rate_rad_s: float) -> None:
        """A body-frame velocity setpoint, in the dialect's frame and type mask."""
        self.sitl.command_velocity(self.dialect.body_frame, self.dialect.body_type_mask, forward_right_down_m_s,
                                   yaw_rate_rad_s)

    def image(self) -> np.ndarray | None:
        """The latest frame's camera image, as the companion receives it."""
        return self.sitl.image()

    # ----- truth -------------------------------------------------------------------------------
    def ground_truth(self) -> dict[str, Any]:
        """The SITL's truth (vehicle and pad NED, touchdown), as ``LandingEnv.ground_truth``."""
        return self.sitl.truth()
