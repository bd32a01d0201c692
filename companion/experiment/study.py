"""The paper's protocol for real people (``col study``): what a participant does, in which order,
and the study folder that records it exactly as the synthetic grid records its trials.

A participant (``S01``, ``S02``, ...) first flies a practice block (demonstrations, not a
trial), then one block per condition (Demo, Int, CoL) in a counterbalanced order: the six
orders of a Williams design for three conditions (each condition in each position, and each
condition after each other one, equally often over six participants). With CoL+ as a fourth
condition (``col_plus``), the four orders of the Williams square for four conditions (the same
balance over four participants). Each condition block is
one trial of the grid's shape, ``Trial(participant, condition, interactions, seed)``: trained
from a fresh random policy on the replicate's training starts, its final policy flown alone on
the grid's held-out starts, and one line in ``results.jsonl``, so the grid's report and
statistics read people and synthetic participants alike. After each condition block the
participant may fill in a raw NASA-TLX (Hart & Staveland 1988; Hart 2006: six scales 0-100,
the raw TLX is their mean), or skip it.

This module is the protocol and the folder (pure logic and file I/O); the console
(:mod:`companion.console.study`) flies the blocks.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from companion.errors import ConfigError, DatasetCorrupt
from companion.experiment.grid import STUDY_PARTICIPANT, Trial
from companion.experiment.results import ResultsFile, TrialResult

CONDITION_ORDERS: tuple[tuple[str, str, str], ...] = (
    ("demo", "int", "col"), ("int", "col", "demo"), ("col", "demo", "int"),
    ("col", "int", "demo"), ("int", "demo", "col"), ("demo", "col", "int"),
)
"""Participant n flies ``CONDITION_ORDERS[(n - 1) % 6]``."""
CONDITION_ORDERS_WITH_COL_PLUS: tuple[tuple[str, ...], ...] = (
    ("demo", "int", "colplus", "col"), ("int", "col", "demo", "colplus"),
    ("col", "colplus", "int", "demo"), ("colplus", "demo", "col", "int"),
)
"""With CoL+: participant n flies ``CONDITION_ORDERS_WITH_COL_PLUS[(n - 1) % 4]`` (rows of the
Williams square 1 2 4 3, each next row one on: every condition once in each position and once
right after each other one)."""
TLX_SCALES = ("mental", "physical", "temporal", "performance", "effort", "frustration")
PLAN_FILE, QUESTIONNAIRE_FILE, PRACTICE_DIR = "study.json", "questionnaire.jsonl", "practice"


def condition_order(participant: str, col_plus: bool = False) -> tuple[str, ...]:
    """The participant's counterbalanced order of conditions (``col_plus``: CoL+ the fourth)."""
    orders = CONDITION_ORDERS_WITH_COL_PLUS if col_plus else CONDITION_ORDERS
    return orders[(participant_number(participant) - 1) % len(orders)]


def participant_number(participant: str) -> int:
    match = STUDY_PARTICIPANT.fullmatch(participant)
    if match is None or int(participant[1:]) < 1:
        raise ConfigError(f"a study participant is S01, S02, ... (S and a number from 01), got {participant!r}")
    return int(participant[1:])


@dataclass(frozen=True)
class Block:
    """One block of the session: the practice, or one condition's trial."""

    kind: str  # "practice" or "trial"
    condition: str
    episodes: int
    trial: Trial | None = None

    @property
    def name(self) -> str:
        return "practice" if self.trial is None else self.trial.key


@dataclass(frozen=True)
class StudyPlan:
    """What one participant's session holds (``study.json``)."""

    participant: str
    interactions: int
    practice_episodes: int
    seed: int = 0
    col_plus: bool = False
    """CoL+ as a fourth condition block."""

    def __post_init__(self) -> None:
        participant_number(self.participant)
        if not 1 <= self.interactions <= 100:
            raise ConfigError(f"--interactions must be 1-100 episodes per condition, got {self.interactions}")
        if not 0 <= self.practice_episodes <= 20:
            raise ConfigError(f"--practice must be 0-20 episodes, got {self.practice_episodes}")
        if self.seed < 0:
            raise ConfigError(f"--seed must be >= 0, got {self.seed}")

    @property
    def order(self) -> tuple[str, ...]:
        return condition_order(self.participant, self.col_plus)

    def blocks(self) -> list[Block]:
        practice = [Block("practice", "demo", self.practice_episodes)] if self.practice_episodes else []
        return practice + [Block("trial", c, self.interactions, Trial(self.participant, c, self.interactions, self.seed))  # type: ignore[arg-type]
                           for c in self.order]


def check_answers(answers: Any) -> dict[str, int]:
    """A raw NASA-TLX: each of the six scales a whole number from 0 to 100."""
    if not isinstance(answers, dict) or set(answers) != set(TLX_SCALES):
        raise ConfigError(f"the questionnaire needs exactly the scales {', '.join(TLX_SCALES)}")
    checked = {}
    for scale in TLX_SCALES:
        value = answers[scale]
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 100:
            raise ConfigError(f"questionnaire scale {scale} must be a whole number from 0 to 100, got {value!r}")
        checked[scale] = value
    return checked


class StudyFolder:
    """One participant's study folder: the plan, the practice run, the trials' runs and lines,
    the questionnaires. What is done is read from the files, so a session resumes after a crash."""

    def __init__(self, root: Path, plan: StudyPlan) -> None:
        self.root, self.plan = root, plan
        self.results = ResultsFile(root / "results.jsonl")

    def open(self) -> StudyFolder:
        """Write the plan, or check that the folder holds this participant's plan."""
        path = self.root / PLAN_FILE
        mine = asdict(self.plan)
        if path.exists():
            try:
                theirs = json.loads(path.read_text())
            except json.JSONDecodeError as exc:
                raise DatasetCorrupt(f"{path} is not JSON ({exc}); move the folder aside") from None
            theirs.setdefault("col_plus", False)  # a plan written before CoL+ had three conditions
            if {k: theirs.get(k) for k in mine} != mine:
                raise ConfigError(f"{self.root} holds another study plan ({theirs}); use another --out "
                                  f"for {self.plan.participant} with these settings")
            return self
        self.root.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({**mine, "order": list(self.plan.order)}, indent=1) + "\n")
        return self

    def run_dir(self, block: Block) -> Path:
        return self.root / PRACTICE_DIR if block.trial is None else self.root / "trials" / block.trial.key / "train"

    def trial_dir(self, block: Block) -> Path:
        assert block.trial is not None
        return self.root / "trials" / block.trial.key

    def flown(self, block: Block) -> int:
        """Episodes of the block flown so far (its run folder's records)."""
        path = self.run_dir(block) / "episodes.jsonl"
        return sum(1 for line in path.read_text().splitlines() if line.strip()) if path.exists() else 0

    def finished_trials(self) -> set[str]:
        return {r.trial.key for r in self.results.load() if r.status == "ok"}

    def answered(self) -> set[str]:
        path = self.root / QUESTIONNAIRE_FILE
        if not path.exists():
            return set()
        return {json.loads(line)["block"] for line in path.read_text().splitlines() if line.strip()}

    def block_done(self, block: Block, finished: set[str]) -> bool:
        if block.trial is None:
            return self.flown(block) >= block.episodes
        return block.trial.key in finished

    def next_block(self) -> Block | None:
        """The first block not yet done; None when the session is over."""
        finished = self.finished_trials()
        return next((b for b in self.plan.blocks() if not self.block_done(b, finished)), None)

    def questionnaire_due(self) -> str | None:
        """The finished condition block whose questionnaire is neither answered nor skipped."""
        finished, answered = self.finished_trials(), self.answered()
        return next((b.name for b in self.plan.blocks() if b.trial is not None and b.name in finished
                     and b.name not in answered), None)

    def record_questionnaire(self, block: str, answers: dict[str, int] | None) -> dict[str, Any]:
        """One questionnaire line (``answers`` None: skipped)."""
        if block != self.questionnaire_due():
            raise ConfigError(f"no questionnaire is due for {block!r}")
        line: dict[str, Any] = {"participant": self.plan.participant, "block": block, "time_unix_s": round(time.time(), 1),
                                "skipped": answers is None, "answers": answers,
                                "raw_tlx": None if answers is None else round(sum(answers.values()) / len(TLX_SCALES), 2)}
        with (self.root / QUESTIONNAIRE_FILE).open("a") as f:
            f.write(json.dumps(line) + "\n")
        return line

    def add_result(self, result: TrialResult) -> None:
        self.results.append(result)

    def status(self) -> dict[str, Any]:
        """The study as the page shows it."""
        finished, upcoming = self.finished_trials(), self.next_block()
        blocks = []
        for b in self.plan.blocks():
            state = "done" if self.block_done(b, finished) else ("next" if b == upcoming else "to do")
            blocks.append({"name": b.name, "kind": b.kind, "condition": b.condition, "episodes": b.episodes,
                           "flown": self.flown(b), "state": state})
        nxt = None
        if upcoming is not None:
            nxt = {"name": upcoming.name, "condition": upcoming.condition,
                   "episodes": upcoming.episodes - self.flown(upcoming)}
        return {"participant": self.plan.participant, "order": list(self.plan.order), "blocks": blocks,
                "next": nxt, "questionnaire_for": self.questionnaire_due(), "scales": list(TLX_SCALES),
                "folder": str(self.root)}
