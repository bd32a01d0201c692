"""The experiment grid: participants x conditions x interactions x seeds, as trials.

A :class:`Trial` names one cell of the grid; with the :class:`ExperimentConfig` and the
companion's config it fully determines a result (see :mod:`companion.experiment.runner`).
The ``[experiment]`` table of a TOML file (``configs/experiment.toml``) becomes an
:class:`ExperimentConfig`; its ``[companion.*]`` and ``[sitl.*]`` tables configure the
companion and the SITL as usual.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator

from colcommon.configio import Section, build, read_toml, section
from companion.config import AskConfig, CompanionConfig, LandingConfig, load_companion_config
from companion.errors import ConfigError
from companion.inputs.operator import operator_named
from companion.inputs.synthetic import PROFILES

TrainCondition = Literal["demo", "int", "col", "colplus", "ask"]
PAPER_CONDITIONS: tuple[TrainCondition, ...] = ("demo", "int", "col")
TRAIN_CONDITIONS: tuple[TrainCondition, ...] = (*PAPER_CONDITIONS, "colplus", "ask")
"""``colplus`` is CoL with the learner switches the ablation supported (companion/learning/col_plus.py);
``ask`` is CoL's schedule with the interventions asked for by the policy (docs/ask-for-help.md)."""
START_SEEDS_PER_REPLICATE = 1000
"""Training starts of replicate ``s`` use seeds ``1000 s, 1000 s + 1, ...`` (never the
held-out evaluation starts, which begin at ``eval_seed``)."""


class ExperimentConfig(Section):
    """[experiment]: the grid and how every trial's final policy is evaluated."""

    participants: tuple[str, ...] = ("P1", "P2", "P3", "P4")
    conditions: tuple[TrainCondition, ...] = PAPER_CONDITIONS
    interactions: tuple[int, ...] = (4, 8, 12, 20)
    seeds: tuple[int, ...] = Field((0,), description="replicates; each gives other training starts and noise")
    eval_runs: int = Field(100, ge=1, description="held-out starts flown by every final policy")
    eval_seed: int = Field(100_000, ge=0, description="seed of the first held-out start")
    updates_per_step: int = Field(40, ge=1, description="budgeted learner: updates per control step")
    prefix_evaluation: bool = Field(
        True, description="Demo and Int train once to the largest count; each count's checkpoint is a prefix")
    eval_inprocess: bool = Field(
        True, description="evaluation runs fly the lockstep SITL in the trial's own process (the same "
        "episodes as over MAVLink, half the CPU; companion/inprocess.py); false: over MAVLink")
    eval_batched: bool = Field(
        True, description="with eval_inprocess: the held-out starts fly through the batched env's lanes, "
        "without the session's link, messages and observer (the same episodes, less CPU; "
        "companion/experiment/batched_eval.py); false: through the in-process session")

    @field_validator("participants")
    @classmethod
    def _known_participants(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        unknown = [p for p in value if p not in PROFILES and operator_named(p) is None]
        if unknown or not value:
            raise ValueError(f"participants must be some of {list(PROFILES)} or the human operator model's "
                             f"H01, H02, ... (companion/inputs/operator.py), got {list(value)}")
        return value

    @field_validator("interactions")
    @classmethod
    def _positive_interactions(cls, value: tuple[int, ...]) -> tuple[int, ...]:
        if not value or any(n < 1 for n in value):
            raise ValueError(f"interactions must be episode counts >= 1, got {list(value)}")
        return value

    @field_validator("seeds")
    @classmethod
    def _replicate_seeds(cls, value: tuple[int, ...]) -> tuple[int, ...]:
        if not value or any(not 0 <= s < 100 for s in value) or len(set(value)) != len(value):
            raise ValueError(f"seeds must be distinct integers in [0, 100), got {list(value)}")
        return value

    @field_validator("conditions")
    @classmethod
    def _some_conditions(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        if not value or len(set(value)) != len(value):
            raise ValueError(f"conditions must be distinct, some of {list(TRAIN_CONDITIONS)}")
        return value


STUDY_PARTICIPANT = re.compile(r"S\d{2,3}")
"""A real person of ``col study`` (companion/experiment/study.py): S01, S02, ..."""


@dataclass(frozen=True)
class Trial:
    """One cell of the grid: who trains, how, for how many episodes, which replicate."""

    participant: str
    condition: TrainCondition
    interactions: int
    seed: int

    def __post_init__(self) -> None:
        known = (self.participant in PROFILES or operator_named(self.participant) is not None
                 or STUDY_PARTICIPANT.fullmatch(self.participant) is not None)
        if not known:
            raise ConfigError(f"unknown participant {self.participant!r}; use one of {list(PROFILES)}, "
                              "the human operator model's H01, H02, ... or a study's S01, S02, ...")
        if self.condition not in TRAIN_CONDITIONS:
            raise ConfigError(f"unknown condition {self.condition!r}; use one of {list(TRAIN_CONDITIONS)}")
        if self.interactions < 1 or self.seed < 0:
            raise ConfigError(f"a trial needs interactions >= 1 and seed >= 0, got {self}")

    @property
    def key(self) -> str:
        """A stable name, used for the trial's folder and to find it in the results file."""
        return f"{self.participant}-{self.condition}-{self.interactions:02d}-s{self.seed}"

    @property
    def start_seed(self) -> int:
        """Seed of the trial's first training start (episode k uses start_seed + k)."""
        return START_SEEDS_PER_REPLICATE * self.seed


PREFIX_CONDITIONS: tuple[TrainCondition, ...] = ("demo", "int")
"""Conditions whose first N episodes are the N-episode trial: the schedule does not depend on
the episode count (CoL's does: N/2 demonstrations, then N/2 interventions)."""


@dataclass(frozen=True)
class TrainingRun:
    """One training run and the trials it answers.

    Demo@N and Int@N are the first N episodes of the longest run (same starts, same seeds,
    training tied to control steps), so one run trained to the largest count answers every
    count: its checkpoint after episode N-1 is Demo@N's final policy. CoL keeps one run per N.
    """

    participant: str
    condition: TrainCondition
    seed: int
    episodes: int
    evaluated_at: tuple[int, ...]

    def __post_init__(self) -> None:
        counts = self.evaluated_at
        if not counts or list(counts) != sorted(set(counts)) or counts[0] < 1 or counts[-1] > self.episodes:
            raise ConfigError(f"a training run is evaluated at increasing counts in [1, episodes], "
                              f"got {counts} for {self.episodes} episodes")
        if self.condition not in PREFIX_CONDITIONS and counts != (self.episodes,):
            raise ConfigError(f"a {self.condition} run answers only its own count {self.episodes}: "
                              "its schedule depends on the episode count")

    @property
    def trials(self) -> list[Trial]:
        return [Trial(self.participant, self.condition, n, self.seed) for n in self.evaluated_at]

    @property
    def key(self) -> str:
        """The key of the trial as long as the run, whose folder holds the training run."""
        return Trial(self.participant, self.condition, self.episodes, self.seed).key

    def only(self, interactions: int) -> TrainingRun:
        """The same run evaluated at one of its counts (to recheck one trial as it was made)."""
        return dataclasses.replace(self, evaluated_at=(interactions,))


def plan(exp: ExperimentConfig, trials: list[Trial] | None = None) -> list[TrainingRun]:
    """The training runs that answer ``trials`` (default: the whole grid), longest first.

    With ``prefix_evaluation`` the Demo and Int trials of one (participant, seed) share a run;
    every other trial is a run of its own.
    """
    trials = expand(exp) if trials is None else trials
    groups: dict[tuple[str, str, int], list[int]] = {}
    runs = []
    for t in trials:
        if exp.prefix_evaluation and t.condition in PREFIX_CONDITIONS:
            groups.setdefault((t.participant, t.condition, t.seed), []).append(t.interactions)
        else:
            runs.append(TrainingRun(t.participant, t.condition, t.seed, t.interactions, (t.interactions,)))
    for (participant, condition, seed), counts in groups.items():
        ordered = tuple(sorted(set(counts)))
        runs.append(TrainingRun(participant, condition, seed, ordered[-1], ordered))  # type: ignore[arg-type]
    return sorted(runs, key=lambda r: -r.episodes)


def expand(exp: ExperimentConfig) -> list[Trial]:
    """Every trial of the grid, longest first (so a pool finishes with short ones)."""
    cells = itertools.product(exp.participants, exp.conditions, exp.interactions, exp.seeds)
    trials = [Trial(p, c, n, s) for p, c, n, s in cells]
    return sorted(trials, key=lambda t: -t.interactions)


@dataclass(frozen=True)
class ExperimentSetup:
    """Everything a trial depends on besides its :class:`Trial`: picklable, for worker processes."""

    exp: ExperimentConfig
    companion: CompanionConfig
    config_path: Path | None = None
    """The file whose ``[sitl]`` tables configure every trial's SITL (None: defaults)."""
    sitl_tables: str = "{}"
    """Those tables as JSON, so that the fingerprint changes with them."""

    def fingerprint(self) -> str:
        """What makes results comparable: evaluation, companion and SITL settings (not the
        grid's extent, so that a grown grid reuses the trials it already ran)."""
        exp = self.exp
        settings = {"eval_runs": exp.eval_runs, "eval_seed": exp.eval_seed,
                    "updates_per_step": exp.updates_per_step,
                    "companion": _fingerprinted(self.companion), "sitl": self.sitl_tables}
        blob = json.dumps(settings, sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]


ADDED_LATER: dict[tuple[str, str], object] = {
    ("learner", "ensemble_members"): 1,
    ("link", "signing_key_file"): "",
    ("session", "end_of_run"): "land",
    ("session", "arm_timeout_s"): 60.0,
    ("session", "clock"): "wall",
    ("perception", "render_rate_hz"): 30.0,
    ("learner", "mirror_augment"): False,
    ("learner", "intervention_weight"): 1.0,
    ("learner", "takeover_steps"): 0,
    ("learner", "takeover_weight"): 1.0,
    ("learner", "holdout_stop"): False,
    ("learner", "demo_noise_std"): 0.0,
    ("learner", "huber_delta"): 0.0,
    ("learner", "holdout_share"): 0.1,
    ("learner", "holdout_block_samples"): 10,
    ("learner", "holdout_check_every_updates"): 100,
    ("learner", "holdout_patience_checks"): 20,
    ("learner", "weight_average_decay"): 0.999,
    ("pilot", "set_down_by_picture"): False,
    ("pilot", "lead_moving_pad"): False,
    ("pilot", "judge_drift_by_picture"): False,
    ("pilot", "drift_time_constant_s"): 0.5,
    ("pilot", "lead_stick_per_m_s"): 0.5,
    ("session", "autopilot_sim_disturbance"): False,
    ("session", "sih_mass_scale"): 1.0,
    ("session", "sih_drag_scale"): 1.0,
    ("session", "policy_pad_ned_m"): None,
    ("session", "touchdown_by_truth_contact"): False,
    ("session", "truth_contact_m"): 0.05,
}
"""Companion settings added after results were committed, with the default that behaves as
before them (one network; every learner switch of docs/learner.md off; no signing; the run's
own SITL is never left by end_of_run; our SITL arms at once; the expert sets down by its
remembered position)."""


EXPERIMENT_LANDING = LandingConfig(touchdown_assist=False)
"""The landing settings of an experiment file that names none (companion.config.EXPERIMENT_TASK)."""


def _fingerprinted(companion: CompanionConfig) -> dict[str, object]:
    """The companion's settings, leaving out those added after results were committed while
    they are at their defaults (ADDED_LATER, asking for help): those results keep their
    fingerprint, and a setting that does change them still changes it."""
    data = companion.model_dump(mode="json")
    for (table, key), default in ADDED_LATER.items():
        if data[table].get(key) == default:
            del data[table][key]
    if data.get("ask") == AskConfig().model_dump(mode="json"):
        del data["ask"]
    if data.get("landing") == EXPERIMENT_LANDING.model_dump(mode="json"):
        del data["landing"]  # the experiments' task as it was designed (companion.config.EXPERIMENT_TASK)
    return data


def load_experiment(path: str | Path) -> ExperimentSetup:
    """An experiment file: ``[experiment]``, and ``[companion]``/``[sitl]`` tables as usual."""
    data = read_toml(path)
    exp = build(ExperimentConfig, section(data, "experiment"), f"[experiment] in {path}")
    sitl_tables = json.dumps(section(data, "sitl"), sort_keys=True)
    companion = load_companion_config(path)
    if "ask" in exp.conditions and companion.learner.ensemble_members < 2:
        raise ConfigError(f"{path}: the ask condition needs an ensemble to measure disagreement: set "
                          "[companion.learner] ensemble_members to 2 or more (5 is usual)")
    return ExperimentSetup(exp, companion, Path(path), sitl_tables)
