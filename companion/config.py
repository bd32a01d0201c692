"""Typed configuration of the companion (the ``[companion]`` tables of a config file).

Defaults are the paper's parameters; ``configs/default.toml`` mirrors them (a test checks).
Each section belongs to the module named in its docstring.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, PositiveInt

from companion.configio import Section, build, read_toml, section
from companion.errors import ConfigError

KNOWN_TOP_LEVEL = {"sitl", "companion", "experiment"}


class LinkConfig(Section):
    """companion.link: how to reach the vehicle."""

    connection: str = "udpin:0.0.0.0:14540"
    source_system: int = Field(1, ge=1, le=255)
    source_component: int = Field(191, ge=1, le=255, description="MAV_COMP_ID_ONBOARD_COMPUTER")
    heartbeat_timeout_s: float = Field(3.0, gt=0)
    link_lost_s: float = Field(1.5, gt=0, description="no telemetry this long -> link lost")
    command_timeout_s: float = Field(1.0, gt=0)
    command_retries: int = Field(3, ge=0)


class CommandsConfig(Section):
    """companion.commands: joystick -> body-frame velocity setpoint."""

    v_xy_max_m_s: float = Field(2.0, gt=0)
    v_z_max_m_s: float = Field(1.0, gt=0)
    yaw_rate_max_rad_s: float = Field(1.0, gt=0)
    deadband: float = Field(0.05, ge=0, lt=1)
    expo: float = Field(0.0, ge=0, le=1)


class SessionConfig(Section):
    """companion.session: the episode loop."""

    control_rate_hz: float = Field(10.5, gt=0)
    max_steps: int = Field(500, gt=0)
    episodes: int = Field(4, gt=0)
    output_dir: str = "runs"


class SafetyConfig(Section):
    """companion.safety: geofence around the start of the session."""

    fence_radius_m: float = Field(30.0, gt=0)
    fence_min_alt_m: float = Field(-1.0, description="below home; -1 allows touching down on the ground")
    fence_max_alt_m: float = Field(25.0, gt=0)


class PerceptionConfig(Section):
    """companion.perception: camera source and pad detector."""

    camera: str = "auto"


class LearnerConfig(Section):
    """companion.learner: the paper's Update-Policy procedure (companion/learner.py)."""

    hidden: tuple[PositiveInt, ...] = Field((130, 72, 40), min_length=1)
    init_std: float = Field(0.1, gt=0, description="std of the normal weight init; biases start at 0")
    learning_rate: float = Field(1e-4, gt=0)
    batch_size: int = Field(64, gt=0)
    loss_threshold: float = Field(0.005, gt=0)
    max_updates: int = Field(2000, gt=0, description="updates per round; a round restarts on new samples")
    torch_threads: int = Field(1, ge=1)
    seed: int = 0
    mode: Literal["thread", "budgeted"] = Field(
        "thread", description="thread: live, as fast as the CPU allows; budgeted: reproducible"
    )
    updates_per_step: int = Field(50, ge=1, description="budgeted mode: updates per control step")
    publish_every_updates: int = Field(
        8, ge=1, description="publish a snapshot at least this often (and after any new data)"
    )


class CompanionConfig(Section):
    link: LinkConfig = LinkConfig()
    commands: CommandsConfig = CommandsConfig()
    session: SessionConfig = SessionConfig()
    safety: SafetyConfig = SafetyConfig()
    perception: PerceptionConfig = PerceptionConfig()
    learner: LearnerConfig = LearnerConfig()


def load_companion_config(path: str | Path | None = None) -> CompanionConfig:
    """The ``[companion]`` part of a config file, or the embedded defaults when ``path`` is None."""
    if path is None:
        return CompanionConfig()
    data = read_toml(path)
    unknown = set(data) - KNOWN_TOP_LEVEL
    if unknown:
        raise ConfigError(
            f"{path}: unknown top-level table(s) {sorted(unknown)}; expected some of "
            f"{sorted(KNOWN_TOP_LEVEL)}"
        )
    return build(CompanionConfig, section(data, "companion"), f"[companion] in {path}")
