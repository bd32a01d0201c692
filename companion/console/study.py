"""The console's side of ``col study``: which block Start may fly, where it flies to, and what
happens when a condition block is complete (its final policy flown alone on the held-out starts,
one results line as the grid writes it). The protocol and the folder are
:mod:`companion.experiment.study`; the runs are the console's own (real time, the person's
gamepad), one fresh run folder, and so one fresh random policy, per block.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from pathlib import Path
from typing import Any

from companion.config import CompanionConfig
from companion.errors import ConfigError
from companion.experiment.grid import ExperimentSetup
from companion.experiment.runner import evaluate_checkpoint, trial_config, trial_result
from companion.experiment.study import Block, StudyFolder, check_answers
from companion.msg.episode import EpisodeRecord

log = logging.getLogger(__name__)
PRACTICE_START_SEED = 900_000
"""The practice block's starts: used by no trial, no evaluation and no calibration."""
_RECORD_FIELDS = {f.name for f in dataclasses.fields(EpisodeRecord)}


def _record(line: dict[str, Any]) -> EpisodeRecord:
    """An ``episodes.jsonl`` line as the record the run wrote."""
    fields: dict[str, Any] = {k: (tuple(v) if isinstance(v, list) else v) for k, v in line.items() if k in _RECORD_FIELDS}
    return EpisodeRecord(**fields)


class ConsoleStudy:
    """One participant's session through the console."""

    def __init__(self, folder: StudyFolder, setup: ExperimentSetup) -> None:
        self.folder, self.setup = folder, setup
        self.block: Block | None = None  # the block flying now
        self._status: dict[str, Any] = {}
        self.refresh()

    def refresh(self) -> None:
        """Read the folder's state again (after an episode, a block, a questionnaire): the page's
        status, sent four times a second under the session's lock, never reads files itself."""
        self._status = {**self.folder.status(), "eval_runs": self.setup.exp.eval_runs,
                        "eval_seed": self.setup.exp.eval_seed}

    def check_start(self, condition: str, episodes: int) -> Block:
        """The block Start flies, if the page asked for exactly it (ConfigError otherwise)."""
        due = self.folder.questionnaire_due()
        if due is not None:
            raise ConfigError(f"first answer (or skip) the questionnaire after block {due}")
        block = self.folder.next_block()
        if block is None:
            raise ConfigError(f"participant {self.folder.plan.participant}'s study is complete; "
                              f"results in {self.folder.root / 'results.jsonl'}")
        remaining = block.episodes - self.folder.flown(block)
        if condition != block.condition or episodes != remaining:
            raise ConfigError(f"the study's next block is {block.name}: {block.condition} with {remaining} "
                              "episodes (the study sets them)")
        self.block = block
        return block

    def run_dir(self, block: Block) -> Path:
        return self.folder.run_dir(block)

    def config(self, block: Block) -> CompanionConfig:
        """The companion's settings for the block: a trial's are the grid's (its learner budget and
        seeds), so a person's trial learns as a synthetic participant's does."""
        return self.setup.companion if block.trial is None else trial_config(self.setup, block.trial)

    def seed(self, block: Block) -> int:
        """The first start's seed: the trial's training starts (those of the grid's replicate)."""
        return PRACTICE_START_SEED if block.trial is None else block.trial.start_seed

    def after_run(self, block: Block) -> dict[str, Any] | None:
        """A condition block whose episodes are all flown becomes a trial: its final policy on
        the held-out starts, and the results line. None while the block is unfinished."""
        if block.trial is None or self.folder.flown(block) < block.episodes:
            return None
        run_dir, trial = self.folder.run_dir(block), block.trial
        records = [json.loads(line) for line in (run_dir / "episodes.jsonl").read_text().splitlines() if line.strip()]
        train = [_record(r) for r in records][:block.episodes]
        checkpoint = run_dir / "checkpoints" / f"episode_{block.episodes - 1:03d}.npz"
        if not checkpoint.exists():
            raise ConfigError(f"block {block.name} has no checkpoint {checkpoint.name}: its last episode did not finish; "
                              "the trial cannot be evaluated")
        cfg = trial_config(self.setup, trial)
        trial_dir = self.folder.trial_dir(block)
        t0 = time.monotonic()
        evaluation = evaluate_checkpoint(self.setup, cfg, checkpoint, trial_dir)
        result = trial_result(self.setup, trial, train, evaluation, eval_wall_s=time.monotonic() - t0,
                         checkpoint=str(checkpoint.relative_to(self.folder.root)))
        self.folder.add_result(result)
        self.refresh()
        log.info("study: %s flew %d of %d held-out starts alone", trial.key, result.eval_successes, result.eval_runs)
        return result.to_json_dict()

    def trial_written(self) -> bool:
        """Whether the block flown last is a finished trial (its line written)."""
        block = self.block
        return block is not None and block.trial is not None and block.trial.key in self.folder.finished_trials()

    def answer(self, answers: Any) -> dict[str, Any]:
        """The questionnaire after the last finished block (None or ``{"skip": true}``: skipped)."""
        due = self.folder.questionnaire_due()
        if due is None:
            raise ConfigError("no questionnaire is due (one follows each finished condition block)")
        checked = None if answers is None else check_answers(answers)
        line = self.folder.record_questionnaire(due, checked)
        self.refresh()
        return line

    def status(self) -> dict[str, Any]:
        return self._status
