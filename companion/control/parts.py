"""What an episode runner is built from (:class:`EpisodeParts`, assembled by the app, fakes in
tests) and the operator's hand on it (:class:`EpisodeControl`, the console)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from companion.commands import CommandMapper
from companion.config import LandingConfig, SessionConfig
from companion.control.ask import AskEvent, HelpAsker
from companion.control.demo_noise import DemoNoise
from companion.control.gaps import GapWatcher
from companion.control.precland import PrecisionLander
from companion.control.records import StepView
from companion.control.safety import Geofence, SetpointLimiter
from companion.control.step import PolicyRunner
from companion.inputs.base import HumanInput
from companion.learning.dataset import HumanDataset
from companion.link.base import VehicleLink
from companion.link.dialect import Dialect
from companion.link.sim_params import AutopilotSim
from companion.link.truth import TRUTH_RATE_HZ
from companion.simulator import SimulatorClient
from companion.vision.observer import Observer


class EpisodeControl(GapWatcher, Protocol):
    """An operator's hand on a running session (the console): watches each step and each gap
    (companion/control/gaps.py) and may end the episode or the run. ``run`` calls
    ``end_requested`` every step; a reason ends the episode now with that outcome."""

    def on_step(self, view: StepView) -> None: ...

    def end_requested(self) -> str | None: ...


@dataclass
class EpisodeParts:
    """Everything an episode runner uses; built by the app, replaced by fakes in tests."""

    link: VehicleLink
    observer: Observer
    mapper: CommandMapper
    human: HumanInput
    fence: Geofence
    limiter: SetpointLimiter
    cfg: SessionConfig
    lockstep: bool
    simulator: SimulatorClient | None = None
    runner: PolicyRunner | None = None
    dataset: HumanDataset | None = None
    dialect: Dialect | None = None  # None: from the vehicle's HEARTBEAT
    control: EpisodeControl | None = None
    asker: HelpAsker | None = None
    on_ask_event: Callable[[AskEvent], None] | None = None
    """Told of every request, answer, hand-back (e.g. a console); the session itself logs
    them, sends them as STATUSTEXT and tells the human input."""
    landing: LandingConfig | None = None
    """Touchdowns the vehicle's land detector recognises (None: send what is asked, as is)."""
    judge_radius_m: float | None = None
    """Without a simulator: judge success from the vehicle's reported position, within this of
    the pad (set with a rendered camera, whose pad is where the estimate puts it); None: unknown."""
    demo_noise: DemoNoise | None = None
    """Stick noise on the demonstration steps the vehicle flies (companion/control/demo_noise.py,
    ``[companion.learner] demo_noise_std``); None: the person's sticks as they are."""
    truth_rate_hz: float = TRUTH_RATE_HZ
    """How often the autopilot's SITL is asked for its truth: the rendered camera's rate
    (``[companion.perception] render_rate_hz``), so each frame has a truth of its own."""
    lander: PrecisionLander | None = None
    """The autopilot's own precision landing flies each episode after its start, fed with
    LANDING_TARGET (companion/control/precland.py); None: the person or the policy flies."""
    autopilot_sim: AutopilotSim | None = None
    """A real autopilot's SITL disturbed at each episode start (companion/link/sim_params.py,
    ``[companion.session] autopilot_sim_disturbance``); None: its simulator as it is."""
