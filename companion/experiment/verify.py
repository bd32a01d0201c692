"""Anyone can check committed results: rerun trials chosen at random, compare their lines.

A trial is a pure function of its settings *and its numeric environment* (docs/experiment.md):
``results.jsonl`` holds nothing that depends on the machine (wall times are in
``timings.jsonl``), and the processes run under the project's numeric profile
(:mod:`colcommon.numeric_env`), recorded in the folder's ``environment.jsonl``. So a trial rerun
from the folder's copy of its experiment file in the same environment must write the very same
line, byte for byte; when it does not, :func:`environment_differences` says what else differs.
The rerun trains the same run the grid trained (a Demo@4 read from a 20-episode run trains
those 20 episodes again) and evaluates the trial's own checkpoint.
"""

from __future__ import annotations

import json
import random
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from colcommon.numeric_env import differences, read_records, record
from companion.errors import ConfigError, DatasetCorrupt
from companion.experiment.grid import TrainingRun, load_experiment
from companion.experiment.results import TrialResult
from companion.experiment.runner import run_training
from companion.experiment.tasks import CONFIG_COPY


@dataclass(frozen=True)
class Check:
    """One rerun trial: the committed line and the rerun's."""

    key: str
    committed: str
    rerun: str

    @property
    def identical(self) -> bool:
        return self.committed == self.rerun

    def differences(self) -> dict[str, tuple[object, object]]:
        """Fields whose values differ: (committed, rerun)."""
        a, b = json.loads(self.committed), json.loads(self.rerun)
        return {k: (a.get(k), b.get(k)) for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)}


def committed_lines(results_dir: Path) -> dict[str, str]:
    """The last finished line of every trial in ``results.jsonl``, exactly as written."""
    path = results_dir / "results.jsonl"
    if not path.exists():
        raise ConfigError(f"{path} does not exist: point --verify at a results folder of `col experiment`")
    lines: dict[str, str] = {}
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        try:
            result = TrialResult.from_json_dict(json.loads(line))
        except (ValueError, TypeError, KeyError) as exc:
            raise DatasetCorrupt(f"{path}:{number} is not a trial result ({exc})") from None
        if result.status == "ok":
            lines[result.trial.key] = line
    return lines


def run_of(result: TrialResult) -> TrainingRun:
    """The training run that made ``result``, read from its checkpoint's folder
    (``trials/<run key>/train/checkpoints/...``), evaluated at the trial's count only."""
    if result.final_checkpoint is None:
        raise DatasetCorrupt(f"trial {result.trial.key} names no checkpoint; it cannot be rerun")
    run_key = PurePosixPath(result.final_checkpoint).parts[1]
    episodes = int(run_key.split("-")[2])
    t = result.trial
    return TrainingRun(t.participant, t.condition, t.seed, episodes, (t.interactions,))


def environment_differences(results_dir: Path) -> list[str]:
    """What differs between the environment the folder's results were made in and this one.

    A folder without a record says so in one line; a folder whose grid ran in segments under
    different environments is compared with its first record, and the change is named too.
    """
    records = read_records(results_dir)
    if not records:
        return [f"{results_dir} has no environment record: its numeric environment is unknown"]
    current = record()
    lines = differences(records[0], current)
    for later in records[1:]:
        within = differences(records[0], later)
        if within:
            lines.insert(0, "the folder's own records differ between segments: " + "; ".join(within))
            break
    return lines


def verify(results_dir: Path, trials: int, work_dir: Path, seed: int | None = None,
           keys: list[str] | None = None) -> list[Check]:
    """Rerun ``trials`` committed trials chosen at random (``seed``), or the trials ``keys``
    name, in ``work_dir``."""
    config = results_dir / CONFIG_COPY
    if not config.exists():
        raise ConfigError(f"{config} is missing: the folder does not say how its trials were run")
    setup = load_experiment(config)
    recorded = json.loads((results_dir / "experiment.json").read_text())["fingerprint"]
    if setup.fingerprint() != recorded:
        raise ConfigError(f"the settings of {config} under this version of the code give fingerprint "
                          f"{setup.fingerprint()}, the results were made with {recorded}: the code's "
                          "defaults changed since; check out the commit that made the results")
    lines = committed_lines(results_dir)
    if keys:
        unknown = [k for k in keys if k not in lines]
        if unknown:
            raise ConfigError(f"no finished trial {', '.join(unknown)} in {results_dir / 'results.jsonl'}")
        chosen = list(keys)
    else:
        if trials < 1 or trials > len(lines):
            raise ConfigError(f"--trials must be in [1, {len(lines)}] (finished trials), got {trials}")
        chosen = random.Random(seed).sample(sorted(lines), trials)
    checks = []
    for key in chosen:
        committed = TrialResult.from_json_dict(json.loads(lines[key]))
        (rerun,) = run_training(setup, run_of(committed), work_dir / key)
        checks.append(Check(key, lines[key], rerun.to_json_line()))
    return checks
