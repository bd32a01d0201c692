"""The session's or the batched evaluation of one checkpoint on N held-out starts, at one clone
(run.sh counts its instructions). Usage: ``CHECKPOINT=FILE python eval_n.py CLONE MODE N``,
MODE ``session`` or ``batched``; prints ``steps S`` (the episodes' control steps)."""

from __future__ import annotations

import dataclasses
import os
import sys
import tempfile
from pathlib import Path


def main() -> None:
    clone, mode, runs = sys.argv[1], sys.argv[2], int(sys.argv[3])
    sys.path.insert(0, clone)
    from companion.experiment.grid import TrainingRun, load_experiment
    from companion.experiment.runner import evaluate_checkpoint, trial_config

    setup = load_experiment(Path(clone) / "configs" / "paper.toml")
    cfg = trial_config(setup, TrainingRun("P2", "col", 0, 4, (4,)))
    if not runs:
        print("steps 0")
        return
    exp = setup.exp.model_copy(update={"eval_inprocess": True, "eval_batched": mode == "batched", "eval_runs": runs})
    with tempfile.TemporaryDirectory() as d:
        res = evaluate_checkpoint(dataclasses.replace(setup, exp=exp), cfg, Path(os.environ["CHECKPOINT"]), Path(d))
    print("steps", sum(r.steps for r in res.records))


if __name__ == "__main__":
    main()
