"""A trial's result and the append-only JSON-lines file that makes a grid resumable.

The grid's parent process is the file's only writer: one line per finished trial, flushed
and synced, so a crash loses at most the trials that were running. A torn last line (a crash
while writing) is ignored on reading and cut before the next append. A trial counts by its
latest ``ok`` line; an ``error`` line never hides one (:func:`companion.statistics.counted`, the
rule the runner, the report, the statistics and ``--verify`` share).
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

from companion.errors import DatasetCorrupt
from companion.experiment.grid import Trial

Status = Literal["ok", "error"]
TIMING_FIELDS = ("train_wall_s", "eval_wall_s")
SUPERVISION_FIELDS = ("requests", "supervised_steps", "watched_steps", "intervention_phase_steps")
"""Written only when set (grids with the ``ask`` condition): earlier results keep their lines."""


@dataclass(frozen=True)
class TrialResult:
    """What one trial produced: its final policy's task completion and the human effort."""

    trial: Trial
    fingerprint: str
    status: Status
    eval_runs: int = 0
    eval_successes: int = 0
    human_samples: int = 0
    interventions: int = 0
    intervened_steps: int = 0
    """Human samples recorded while intervening (intervention-phase episodes only)."""
    missed_takeovers: int = 0
    """Intervention-phase episodes that failed with no take-over at all."""
    train_successes: int = 0
    train_wall_s: float = 0.0
    eval_wall_s: float = 0.0
    final_checkpoint: str | None = None
    error: str | None = None
    requests: int | None = None
    """Grids with the ``ask`` condition (else None, left out of the line): requests for help in
    training, and the steps the person had to watch - in all training episodes
    (``supervised_steps``), in the intervention-phase episodes alone (``watched_steps``), out
    of all steps of those episodes (``intervention_phase_steps``)."""
    supervised_steps: int | None = None
    watched_steps: int | None = None
    intervention_phase_steps: int | None = None

    def __post_init__(self) -> None:
        if self.status not in ("ok", "error"):
            raise ValueError(f"status must be 'ok' or 'error', got {self.status!r}")
        if self.status == "ok" and not 0 <= self.eval_successes <= self.eval_runs:
            raise ValueError(f"eval_successes must be in [0, eval_runs], got {self.eval_successes}/{self.eval_runs}")

    @property
    def completion_pct(self) -> float:
        """Task completion of the final policy on the held-out starts, in percent."""
        return 100.0 * self.eval_successes / self.eval_runs if self.eval_runs else 0.0

    def to_json_dict(self) -> dict[str, Any]:
        """What the trial produced, and nothing that depends on the machine: wall times are
        written apart (:meth:`timing`), so a rerun of a trial writes the same line."""
        data = {k: v for k, v in asdict(self).items()
                if k not in TIMING_FIELDS and not (k in SUPERVISION_FIELDS and v is None)}
        data["trial"]["key"] = self.trial.key
        return data

    def to_json_line(self) -> str:
        return json.dumps(self.to_json_dict())

    def timing(self) -> dict[str, Any]:
        return {"trial": self.trial.key, **{k: getattr(self, k) for k in TIMING_FIELDS}}

    @classmethod
    def from_json_dict(cls, data: dict[str, Any]) -> TrialResult:
        trial_data = {k: v for k, v in data["trial"].items() if k != "key"}
        return cls(**{**data, "trial": Trial(**trial_data)})


class ResultsFile:
    """``results.jsonl``: one :class:`TrialResult` a line, appended as trials finish."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def load(self) -> list[TrialResult]:
        """Every complete line, in order (a torn last line is skipped)."""
        if not self.path.exists():
            return []
        lines = self.path.read_text().splitlines()
        results = []
        for number, line in enumerate(lines, start=1):
            if not line.strip():
                continue
            try:
                results.append(TrialResult.from_json_dict(json.loads(line)))
            except (ValueError, TypeError, KeyError) as exc:
                if number == len(lines):
                    break  # torn by a crash while writing: that trial runs again
                raise DatasetCorrupt(f"{self.path}:{number} is not a trial result ({exc}); "
                                     "delete that line or write to another --out folder") from None
        return results

    def finished(self, fingerprint: str) -> dict[str, TrialResult]:
        """Trials already done with these settings, by key (errors are not done)."""
        done = {}
        for result in self.load():
            if result.status == "ok" and result.fingerprint == fingerprint:
                done[result.trial.key] = result
        return done

    @property
    def timings_path(self) -> Path:
        """``timings.jsonl`` beside the results: wall times, which differ from run to run."""
        return self.path.with_name("timings.jsonl")

    def append(self, result: TrialResult) -> None:
        """Add one line and make it durable before returning (its wall times go apart)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._drop_torn_tail()
        with self.path.open("a") as fh:
            fh.write(result.to_json_line() + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        with self.timings_path.open("a") as fh:
            fh.write(json.dumps(result.timing()) + "\n")

    def _drop_torn_tail(self) -> None:
        """Cut a line left unfinished by a crash (its trial runs again), so lines stay whole."""
        if not self.path.exists():
            return
        data = self.path.read_bytes()
        if data and not data.endswith(b"\n"):
            with self.path.open("r+b") as fh:
                fh.truncate(data.rfind(b"\n") + 1)
