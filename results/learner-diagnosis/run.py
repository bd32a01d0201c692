"""Why the policies fail: the diagnosis preregistered in docs/learner.md ("Why the policies fail:
the diagnosis plan", committed in 78488a8 before any of these runs).

The 24 policies: CoL@20 and Demo@20 of P1-P4, replicate 0, from the pinned paper grid
(results/paper-grid), then of H01-H08, replicate 0, from the human-like grid (results/human-like).
Steps, from the repository's root, each resumable (a policy whose output exists is skipped):

    python results/learner-diagnosis/run.py code [--commit C]   # the code the diagnosis runs: a clean export
    python results/learner-diagnosis/run.py verify [KEY ...]    # retrain: col experiment --verify --keep
    python results/learner-diagnosis/run.py fly [KEY ...]       # endpoints 1-3 on the identical reruns
    python results/learner-diagnosis/run.py teacher-check [KEY ...]  # the shadow teacher replays its own labels
    python results/learner-diagnosis/run.py fit [KEY ...]       # endpoint 4 (converged, reseeded; each flown)
    python results/learner-diagnosis/run.py summarise           # summary.json and table.md

Without KEYs a step takes every policy, the paper grid's first. Every step after `code` runs
the library of one commit, exported clean (`git archive`) to runs/learner-diagnosis/code/ (its
commit in COMMIT there), whatever the working tree holds meanwhile: the export comes first on
the import path, and the reruns and their SITLs run from inside it. The script re-executes itself
under the project's numeric profile (colcommon/numeric_env.py), as `col experiment` does, so
its flights are the experiment's evaluation bit for bit (each flight of a final policy is
checked against the rerun's own eval_episodes.jsonl).

Run folders (the reruns' datasets and checkpoints, per-step arrays) go to runs/learner-diagnosis/,
which is not committed. What is committed here: verify.jsonl (every rerun's verdict),
episodes/<grid>/<policy>.jsonl (one line per held-out start: outcome, distance, phases, the
teacher's action gaps, nearest-neighbour distances), fit/<policy>.json (endpoint 4's training
records) and the summaries.
"""

from __future__ import annotations

import sys

if __name__ == "__main__":  # before numpy loads: the numeric profile the grids were made under
    _root = __import__("pathlib").Path(__file__).resolve().parents[2]
    _code = _root / "runs" / "learner-diagnosis" / "code"
    sys.path.insert(0, str(_code if (_code / "COMMIT").exists() and sys.argv[1:2] != ["code"] else _root))
    from colcommon.numeric_env import ensure_pinned

    _why = ensure_pinned(sys.argv)
    if _why is not None:
        print(f"numeric profile not applied: {_why}", file=sys.stderr)

import argparse
import json
import os
import shutil
import subprocess
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
RUNS = ROOT / "runs" / "learner-diagnosis"
GRIDS = {"paper-grid": ("P1", "P2", "P3", "P4"),
         "human-like": tuple(f"H{i:02d}" for i in range(1, 9))}
CONDITIONS = ("col", "demo")
POLICIES: list[tuple[str, str]] = [(grid, f"{p}-{c}-20-s0") for grid, people in GRIDS.items()
                                   for c in CONDITIONS for p in people]
CODE = RUNS / "code"
VERIFY = HERE / "verify.jsonl"


def _rel(path: Path) -> str:
    """A path as the commands (run from the repository's root) name it."""
    return os.path.relpath(path, ROOT)


def grid_of(key: str) -> str:
    for grid, key2 in POLICIES:
        if key2 == key:
            return grid
    raise SystemExit(f"{key} is not one of the diagnosed policies: {', '.join(k for _, k in POLICIES)}")


def chosen(keys: list[str]) -> list[tuple[str, str]]:
    return [(grid_of(k), k) for k in keys] if keys else list(POLICIES)


def export_code(at: str = "HEAD") -> None:
    """runs/learner-diagnosis/code/: the repository at ``at`` as committed (``git archive``), so the
    diagnosis runs one commit's library while the working tree changes (another machine continues
    with the commit RUN.md names, 1a59533)."""
    from colcommon.code_export import export_commit  # the step runs from the repository, not an export

    head, made = export_commit(ROOT, CODE, at)
    print(f"{_rel(CODE)}: {head}" if made else f"{_rel(CODE)} holds {head[:7]} already")


def commit() -> str:
    """The commit whose library the steps run (the export's)."""
    return (CODE / "COMMIT").read_text().strip()[:7]


def code_env() -> dict[str, str]:
    """The environment of a subprocess that runs the exported library."""
    return {**os.environ, "PYTHONPATH": str(CODE)}


# ----- step 1: the reruns -----------------------------------------------------------------------
def verdicts() -> dict[str, dict]:
    """The last verdict of every rerun policy (verify.jsonl)."""
    if not VERIFY.exists():
        return {}
    return {r["key"]: r for r in (json.loads(line) for line in VERIFY.read_text().splitlines() if line.strip())}


def kept(grid: str, key: str) -> Path:
    """The rerun's output folder (``--keep``): trials/<key>/train and trials/<key>/eval_episodes.jsonl."""
    return RUNS / grid / key / key


def verify(keys: list[str]) -> None:
    """``col experiment --verify results/<grid> --trial KEY --keep runs/learner-diagnosis/<grid>/KEY``,
    one policy at a time; its verdict goes to verify.jsonl. A policy verified before whose kept
    folder is gone (another machine: runs/ is not committed) is rerun, its new verdict appended."""
    done = verdicts()
    for grid, key in chosen(keys):
        if key in done and kept(grid, key).exists():
            continue
        keep = RUNS / grid / key
        shutil.rmtree(keep, ignore_errors=True)  # an interrupted rerun starts over
        keep.parent.mkdir(parents=True, exist_ok=True)
        log = RUNS / grid / f"{key}.verify.log"
        cmd = ["col", "experiment", "--verify", f"results/{grid}", "--trial", key, "--keep", _rel(keep)]
        print(" ".join(cmd), flush=True)
        with log.open("w") as out:  # from inside the export: its results/<grid> are the committed ones
            code = subprocess.run([str(ROOT / ".venv" / "bin" / "col"), *cmd[1:-1], str(keep)], stdout=out,
                                  stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, cwd=CODE, env=code_env()).returncode
        lines = log.read_text().splitlines()
        summary = next((json.loads(line) for line in reversed(lines) if line.startswith("{\"verified\"")), None)
        per_trial = [line for line in lines if line.startswith(f"{key}: ")]
        if summary is None or not per_trial:
            raise SystemExit(f"{' '.join(cmd)} gave no verdict (exit {code}); see {_rel(log)}")
        record = {"grid": grid, "key": key, "identical": summary["identical"] == 1 and code == 0,
                  "verdict": per_trial[-1], "environment_differences": summary["environment_differences"],
                  "exit_code": code, "command": " ".join(cmd), "commit": commit()}
        with VERIFY.open("a") as fh:
            fh.write(json.dumps(record) + "\n")
        print(per_trial[-1], flush=True)


# ----- steps 2 and 3: the policy alone on the held-out starts, the teacher in its shadow -------------
FINAL_M = 1.0  # final descent: at most this high above the pad (ground truth)
LAST_S = 2.0  # a failure is placed at the phase of its last 2 s
PHASES = ("search", "approach", "final")
MODES = ("seen", "remembered", "blink", "search", "lapse")
"""The teacher's source of each command: the pad in view; committed to touchdown with the pad
not seen whole, steering to where it was last seen whole (the remembered position: "memory");
the pad lost for less than ``lost_hold_s``, the last command repeated; lost for longer, brake
and climb; not looking (a lapse), the last command held."""
AXES = ("roll", "pitch", "yaw", "throttle")


def _setup(grid: str):
    from companion.experiment.grid import load_experiment

    return load_experiment(Path("results") / grid / "config.toml")


def _run_of(key: str):
    from companion.experiment.grid import TrainingRun

    participant, condition, count, seed = key.split("-")
    return TrainingRun(participant, condition, int(seed[1:]), int(count), (int(count),))


def trial_cfg(grid: str, key: str):
    """The setup and the companion config the trial ran with (the runner's own)."""
    from companion.experiment.runner import trial_config

    setup = _setup(grid)
    return setup, trial_config(setup, _run_of(key))


class Teacher:
    """The trial's participant (built as the session built it: ``build_human("synthetic:<name>")``
    with the trial's config) reading every observation the policy acts on; its answers are only
    recorded, never flown. Before each held-out start it is reset to its state at the trial's last
    training episode (the operator model's fatigue of that episode), with its noise drawn from
    ``[participant seed, trial seed, start's seed]`` (fresh draws per start, none shared with
    training). Its scripted expert's branches are watched to tell where a command came from."""

    def __init__(self, human, last_episode: int) -> None:
        self.human = human
        self.last_episode = last_episode
        outer = human
        intervening = getattr(outer, "inner", None) or getattr(outer, "expert")  # SyntheticPilot / operator
        self.expert = intervening.expert  # the ScriptedExpert whose sticks the participant moves
        self.seed = outer.profile.seed if hasattr(outer, "profile") else outer.base.seed
        self.mode = "seen"
        self.intent = None
        read, set_down, pad_lost = intervening.read, self.expert._set_down, self.expert._pad_lost
        lost_hold_ms = self.expert.cfg.lost_hold_s * 1000.0

        def watched_read(obs):
            answer = read(obs)
            self.intent = answer.command.to_array()
            return answer

        def watched_set_down(*args):
            self.mode = "remembered"
            return set_down(*args)

        def watched_pad_lost(vel, now_ms):
            seen = self.expert._last_seen_ms
            self.mode = "blink" if seen is not None and now_ms - seen < lost_hold_ms else "search"
            return pad_lost(vel, now_ms)

        intervening.read = watched_read
        self.expert._set_down = watched_set_down
        self.expert._pad_lost = watched_pad_lost

    def start(self, seed: int) -> None:
        import numpy as np

        h = self.human
        h._resets = self.last_episode
        h.reset()  # the participant as at its last training episode
        h.rng = np.random.default_rng([self.seed, h.trial_seed, seed])
        if hasattr(h, "takeover"):
            h.takeover.rng = h.rng

    def read(self, obs):
        """(command, intent or None, mode, override held)."""
        self.mode, self.intent = "seen", None
        lapses = self.human.lapses
        answer = self.human.read(obs)
        if self.human.lapses != lapses:
            return answer.command.to_array(), None, "lapse", answer.override_held
        return answer.command.to_array(), self.intent, self.mode, answer.override_held


def shadow_evaluator_class():
    """:class:`BatchedEvaluator` with the teacher beside it and every step recorded. Its flight is
    the class's own: only reads are added (the detections it makes anyway, the ground truth)."""
    import numpy as np

    from companion.experiment.batched_eval import BatchedEvaluator
    from companion.learning.ensemble import disagreement
    from companion.vision.observation import Observation, normalised
    from companion.vision.observation_rows import detect_pad, pad_rows, telemetry_row

    class ShadowEvaluator(BatchedEvaluator):
        def __init__(self, cfg, snapshot, sitl_cfg, teacher: Teacher) -> None:
            super().__init__(cfg, snapshot, sitl_cfg, 1)
            self.teacher = teacher
            self.rows: list[tuple] = []
            self._detections: dict = {}

        def _next(self, i, todo, flights) -> None:
            super()._next(i, todo, flights)
            if i in flights:
                self.teacher.start(flights[i].seed)

        def _observations(self, indices):  # the class's own, keeping the detections
            telemetry = np.array([telemetry_row(self._snap(i), self._relative(i)) for i in indices]).reshape(-1, 12)
            detections = [detect_pad(self._detector, self.lanes[i].sitl.image()) for i in indices]
            self._detections = dict(zip(indices, detections, strict=True))
            return normalised(telemetry, pad_rows(detections, self._image_size))

        def _act(self, flights, acting) -> None:
            for i, vector in acting:
                snap = self._snap(i)
                pad = self._detections[i]
                stamp = snap.frame_time_boot_ms if snap.frame_time_boot_ms is not None else snap.time_boot_ms
                obs = Observation(position_ned_m=self._relative(i), attitude_rad=snap.attitude_rad,
                                  velocity_ned_m_s=snap.velocity_ned_m_s, rates_frd_rad_s=snap.rates_frd_rad_s,
                                  pad=pad, image_size_px=self._image_size, time_boot_ms=max(0, int(stamp)))
                command, intent, mode, override = self.teacher.read(obs)
                action, _ = disagreement(self.snapshot, vector.copy())
                truth = self.lanes[i].sitl.truth()
                vehicle, pad_ned = np.array(truth["vehicle_ned"]), np.array(truth["pad_ned"])
                self.rows.append((flights[i].episode, flights[i].step, vector.copy(), np.asarray(action, float),
                                  command, np.full(4, np.nan) if intent is None else intent, MODES.index(mode),
                                  bool(override), float(pad_ned[2] - vehicle[2]),
                                  float(np.hypot(*(vehicle[:2] - pad_ned[:2]))), pad is not None,
                                  pad is not None and pad.partial))
            super()._act(flights, acting)

        def arrays(self) -> dict:
            r = self.rows
            return {"episode": np.array([x[0] for x in r], np.int32), "step": np.array([x[1] for x in r], np.int32),
                    "obs": np.array([x[2] for x in r], np.float32).reshape(-1, 15),
                    "action": np.array([x[3] for x in r]).reshape(-1, 4), "teacher": np.array([x[4] for x in r]).reshape(-1, 4),
                    "intent": np.array([x[5] for x in r]).reshape(-1, 4), "mode": np.array([x[6] for x in r], np.int8),
                    "override": np.array([x[7] for x in r], bool), "height_m": np.array([x[8] for x in r]),
                    "horizontal_m": np.array([x[9] for x in r]), "visible": np.array([x[10] for x in r], bool),
                    "partial": np.array([x[11] for x in r], bool)}

    return ShadowEvaluator


def phases_of(height_m, visible):
    """0 search (pad not visible, above 1 m), 1 approach (visible, above 1 m), 2 final descent
    (at most 1 m above the pad, whatever the detector says)."""
    import numpy as np

    return np.where(height_m <= FINAL_M, 2, np.where(visible, 1, 0)).astype(np.int8)


def fly_policy(grid: str, key: str, checkpoint: Path, name: str, compare: Path | None) -> None:
    """Fly ``checkpoint`` on the grid's held-out starts with the teacher in its shadow; write
    episodes/<grid>/<name>.jsonl (committed) and the per-step arrays (runs/)."""
    import numpy as np
    from scipy.spatial import cKDTree

    from companion.app import RunOptions, build_human
    from companion.experiment.batched_eval import eval_policy
    from companion.inprocess import sitl_config_for
    from companion.learning.dataset import load_csv

    out = HERE / "episodes" / grid / f"{name}.jsonl"
    if out.exists():
        return
    setup, cfg = trial_cfg(grid, key)
    first, runs = setup.exp.eval_seed, setup.exp.eval_runs
    teacher = Teacher(build_human(f"synthetic:{key.split('-')[0]}", cfg), last_episode=int(key.split("-")[2]) - 1)
    snapshot = eval_policy(cfg, checkpoint)
    sitl_cfg = sitl_config_for(RunOptions(config_path=setup.config_path, seed=first))
    with shadow_evaluator_class()(cfg, snapshot, sitl_cfg, teacher) as evaluator:
        records = evaluator.run((k, first + k) for k in range(runs))
        steps = evaluator.arrays()
    train = load_csv(kept(grid, key) / "trials" / key / "train" / "human.csv")
    steps["nn"], _ = cKDTree(train.obs.astype(np.float64)).query(steps["obs"].astype(np.float64), k=1)
    steps["phase"] = phases_of(steps["height_m"], steps["visible"])
    arrays = RUNS / grid / "steps" / f"{name}.npz"
    arrays.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(arrays, **steps)
    committed = compare.read_text().splitlines() if compare is not None else None
    last_steps = max(1, round(LAST_S * cfg.session.control_rate_hz))
    lines = []
    for record in records:
        lines.append(json.dumps(episode_line(record, steps, committed, last_steps, len(train.obs))))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    same = None if committed is None else sum(json.loads(x)["same_as_evaluation"] for x in lines)
    print(f"{name}: {sum(bool(r.success) for r in records)}/{len(records)} landed"
          + ("" if same is None else f"; {same}/{len(records)} episode records as in the rerun's evaluation"), flush=True)


def _mean(values) -> float | None:
    import numpy as np

    return None if len(values) == 0 else round(float(np.mean(values)), 5)


def _cell(mask, steps) -> dict:
    """The teacher's gap and the nearest-neighbour distance over the steps of ``mask``."""
    import numpy as np

    gap = steps["teacher"][mask] - steps["action"][mask]
    intent = steps["intent"][mask] - steps["action"][mask]
    has_intent = np.isfinite(intent).all(axis=1)
    return {"n": int(mask.sum()),
            "gap_norm": _mean(np.linalg.norm(gap, axis=1)),
            "gap_abs": None if not mask.any() else [round(float(v), 5) for v in np.abs(gap).mean(axis=0)],
            "intent_n": int(has_intent.sum()),
            "intent_gap_norm": _mean(np.linalg.norm(intent[has_intent], axis=1)),
            "nn": _mean(steps["nn"][mask]),
            "override": int(steps["override"][mask].sum())}


def episode_line(record, steps, committed: list[str] | None, last_steps: int, train_rows: int) -> dict:
    """One held-out start: outcome, kind, distance, phases and the teacher's gaps (cells of steps:
    n, mean gap norm, mean |gap| per axis (roll, pitch, yaw, throttle), the same against the
    teacher's intent (its expert's sticks before the hand's noise and lag; none in a lapse), mean
    nearest-neighbour distance to the training observations, steps where the teacher would hold
    the override)."""
    import numpy as np

    mine = steps["episode"] == record.episode
    phase, mode = steps["phase"][mine], steps["mode"][mine]
    height, horizontal = steps["height_m"][mine], steps["horizontal_m"][mine]
    kind = ("landed" if record.success else "off_pad") if record.outcome == "touchdown" else record.outcome
    end = phase[-last_steps:]
    counts = [int((end == p).sum()) for p in range(3)]
    sub = {k: v[mine] for k, v in steps.items()}
    line = {
        "episode": record.episode, "seed": record.seed, "outcome": record.outcome, "success": bool(record.success),
        "kind": kind, "steps": record.steps, "touchdown_distance_m": record.touchdown_distance_m,
        "closest_approach_m": None if not mine.any() else round(float(np.min(np.hypot(height, horizontal))), 4),
        "closest_horizontal_m": None if not mine.any() else round(float(np.min(horizontal)), 4),
        "end_height_m": None if not mine.any() else round(float(height[-1]), 4),
        "end_horizontal_m": None if not mine.any() else round(float(horizontal[-1]), 4),
        "end_phase": None if not mine.any() else PHASES[max(range(3), key=lambda j: (counts[j], j))],
        "phase_steps": {p: int((phase == j).sum()) for j, p in enumerate(PHASES)},
        "mode_steps": {m: int((mode == j).sum()) for j, m in enumerate(MODES)},
        "by_phase": {p: _cell(sub["phase"] == j, sub) for j, p in enumerate(PHASES)},
        "by_memory": {"remembered": _cell(sub["mode"] == MODES.index("remembered"), sub),
                      "not": _cell(sub["mode"] != MODES.index("remembered"), sub)},
        "final_by_memory": {"remembered": _cell((sub["phase"] == 2) & (sub["mode"] == MODES.index("remembered")), sub),
                            "not": _cell((sub["phase"] == 2) & (sub["mode"] != MODES.index("remembered")), sub)},
        "all": _cell(np.ones(int(mine.sum()), bool), sub),
        "training_rows": train_rows,
    }
    if committed is not None:
        line["same_as_evaluation"] = json.dumps(record.to_json_dict()) == committed[record.episode]
    return line


def fly(keys: list[str]) -> None:
    """Endpoints 1-3 for every final policy whose rerun was identical."""
    done = verdicts()
    for grid, key in chosen(keys):
        if key not in done:
            print(f"{key}: not rerun yet (step verify)")
            continue
        if not done[key]["identical"]:
            print(f"{key}: its rerun differs from the committed line; listed, not diagnosed")
            continue
        trial = kept(grid, key) / "trials" / key
        training = HERE / "training" / grid / f"{key}.jsonl"  # endpoint 4's fit after each episode
        if not training.exists():
            training.parent.mkdir(parents=True, exist_ok=True)
            lines = [json.loads(x) for x in (trial / "train" / "episodes.jsonl").read_text().splitlines() if x.strip()]
            training.write_text("".join(json.dumps({k: v for k, v in x.items() if k != "wall_time_s"}) + "\n"
                                        for x in lines))
        fly_policy(grid, key, trial / "train" / "checkpoints" / f"episode_{int(key.split('-')[2]) - 1:03d}.npz",
                   key, trial / "eval_episodes.jsonl")


# ----- step 4: fit and stability --------------------------------------------------------------------
HELD_OUT = 0.10  # the converged policy's early stopping: loss on this share of the samples
PATIENCE = 2000  # updates without a better held-out loss
CHECK_EVERY = 100  # held-out loss measured every this many updates
MAX_UPDATES = 400_000  # a bound, never expected to be reached
SPLIT_SEED = 20261203  # which samples are held out
RESEEDS = (1, 2, 3, 4, 5)  # minibatch seeds of the redone last updates (the trials' own: 1000 x replicate = 0)
WARM_UPDATES = 1000  # RMSProp's square averages rebuilt at the weights before the last episode (lr 0)
WARM_SEED = 99


class Rows:
    """A fixed dataset as the learner reads one (``SampleSource``)."""

    def __init__(self, obs, actions) -> None:
        from companion.learning.dataset import DatasetView

        self._view = DatasetView(obs, actions)

    def __len__(self) -> int:
        return len(self._view)

    def view(self):
        return self._view

    def wait_for_growth(self, known: int, timeout_s: float) -> int:
        return len(self._view)


def _mse(snapshot, obs, actions) -> float:
    import numpy as np

    return float(np.mean((snapshot.act(obs) - actions) ** 2))


def converge(cfg, obs, actions) -> tuple[object, dict]:
    """The trial's network from its own initial weights (the learner seed), the same optimiser
    and minibatch size, on 90 % of the final dataset until the loss on the other 10 % has not
    improved for 2,000 updates; the weights at the best held-out loss."""
    import numpy as np

    from companion.learning.learner import Learner

    order = np.random.default_rng(SPLIT_SEED).permutation(len(obs))
    held = order[:int(np.ceil(HELD_OUT * len(obs)))]
    fit = np.sort(order[len(held):])
    learner = Learner(cfg.learner, Rows(obs[fit], actions[fit]))
    best, best_loss, best_at, curve = learner.publish(), _mse(learner.latest_snapshot, obs[held], actions[held]), 0, []
    while learner.updates - best_at < PATIENCE and learner.updates < MAX_UPDATES:
        for _ in range(CHECK_EVERY):
            learner.step()
        snap = learner.publish()
        loss = _mse(snap, obs[held], actions[held])
        curve.append([learner.updates, round(loss, 6)])
        if loss < best_loss:
            best, best_loss, best_at = snap, loss, learner.updates
    record = {"updates_run": learner.updates, "best_update": best_at, "held_out_rows": len(held),
              "held_out_loss": round(best_loss, 6), "fit_loss": round(_mse(best, obs[fit], actions[fit]), 6),
              "loss_all": round(_mse(best, obs, actions), 6), "held_out_curve": curve[::10] + curve[-1:],
              "split_seed": SPLIT_SEED}
    return best, record


def reseed(cfg, before, before_size: int, updates: int, obs, actions, seed: int):
    """The policy before the last episode's updates, those ``updates`` redone on the final dataset
    with minibatch seed ``seed``. The checkpoint holds no optimiser state: RMSProp's square
    averages are rebuilt first, by WARM_UPDATES updates at learning rate 0 (weights unchanged) on
    the dataset as it was before the last episode."""
    from companion.learning.learner import Learner

    warm = Learner(cfg.learner.model_copy(update={"learning_rate": 0.0, "seed": WARM_SEED}),
                   Rows(obs[:before_size], actions[:before_size]), initial=before)
    for _ in range(WARM_UPDATES):
        warm.step()
    learner = Learner(cfg.learner.model_copy(update={"seed": seed}), Rows(obs, actions), initial=before)
    learner.trainer.load_state(warm.trainer.state())
    for _ in range(updates):
        learner.step()
    return learner.publish()


def fit_policy(grid: str, key: str) -> None:
    """Endpoint 4 for one policy: fit/<key>.json, then its converged and reseeded policies flown."""
    from companion.learning.checkpoint import load_checkpoint, save_checkpoint
    from companion.learning.dataset import load_csv

    record_path = HERE / "fit" / f"{key}.json"
    train = kept(grid, key) / "trials" / key / "train"
    last = int(key.split("-")[2]) - 1
    folder = RUNS / grid / "fit" / key
    folder.mkdir(parents=True, exist_ok=True)
    if not record_path.exists():
        setup, cfg = trial_cfg(grid, key)
        rows = load_csv(train / "human.csv")
        obs, actions = rows.obs, rows.actions
        final, final_meta = load_checkpoint(train / "checkpoints" / f"episode_{last:03d}.npz")
        before, before_meta = load_checkpoint(train / "checkpoints" / f"episode_{last - 1:03d}.npz")
        episodes = [json.loads(x) for x in (train / "episodes.jsonl").read_text().splitlines() if x.strip()]
        record = {"key": key, "grid": grid, "rows": len(obs),
                  "episodes": [{k: e.get(k) for k in ("episode", "phase", "success", "dataset_size", "policy_version",
                                                      "loss_all", "loss_intervention", "interventions")} for e in episodes],
                  "final": {"version": final.version, "loss_all": round(_mse(final, obs, actions), 6)}}
        best, record["converged"] = converge(cfg, obs, actions)
        save_checkpoint(folder / "converged.npz", best, cfg.learner, dataset_size=len(obs), episode=last,
                        condition=key.split("-")[1], extra={"diagnosis": "converged"})
        updates = final.version - before.version
        record["last_updates"] = {"before_version": before.version, "before_dataset_size": before_meta.dataset_size,
                                  "updates": updates, "warm_updates": WARM_UPDATES, "seeds": []}
        for seed in RESEEDS:
            snap = reseed(cfg, before, before_meta.dataset_size, updates, obs, actions, seed)
            save_checkpoint(folder / f"reseed-{seed}.npz", snap, cfg.learner, dataset_size=len(obs), episode=last,
                            condition=key.split("-")[1], extra={"diagnosis": f"reseed {seed}"})
            record["last_updates"]["seeds"].append({"seed": seed, "loss_all": round(_mse(snap, obs, actions), 6)})
        record["commit"] = commit()
        record_path.parent.mkdir(parents=True, exist_ok=True)
        record_path.write_text(json.dumps(record, indent=1) + "\n")
        print(f"{key}: converged at update {record['converged']['best_update']} (held-out loss "
              f"{record['converged']['held_out_loss']}); last episode's {updates} updates redone", flush=True)
    fly_policy(grid, key, folder / "converged.npz", f"{key}--converged", None)
    for seed in RESEEDS:
        fly_policy(grid, key, folder / f"reseed-{seed}.npz", f"{key}--reseed-{seed}", None)


def fit(keys: list[str]) -> None:
    done = verdicts()
    for grid, key in chosen(keys):
        if key in done and done[key]["identical"] and (HERE / "episodes" / grid / f"{key}.jsonl").exists():
            fit_policy(grid, key)
        else:
            print(f"{key}: not yet rerun identically and flown (steps verify, fly)")


# ----- a check of the shadow teacher: it replays its own labels -------------------------------------
def teacher_check(keys: list[str]) -> None:
    """teacher_check.jsonl: the teacher (built as in ``fly_policy``) reset as at training episode
    k and fed the observations recorded in training episodes 0-2 (demonstrations in both
    conditions), rebuilt from the dataset's normalised values (the pad's pixels from its three
    entries, ``partial`` where its circle crosses the image's border, the time from ``time_s``):
    how far its answers are from the recorded labels. Beside it, the final policy's own gap to
    every label of its dataset (the same norm of the 4 sticks)."""
    import numpy as np

    from companion.app import RunOptions, build_human
    from companion.inprocess import sitl_config_for
    from companion.learning.checkpoint import load_checkpoint
    from companion.learning.dataset import load_csv
    from companion.vision.observation import Observation
    from companion.vision.perception import PadDetection

    out = HERE / "teacher_check.jsonl"
    have = {json.loads(x)["key"] for x in out.read_text().splitlines()} if out.exists() else set()
    done = verdicts()
    for grid, key in chosen(keys):
        if key in have or key not in done or not done[key]["identical"]:
            continue
        setup, cfg = trial_cfg(grid, key)
        camera = sitl_config_for(RunOptions(config_path=setup.config_path, seed=0)).camera
        w, h = camera.width_px, camera.height_px
        train = kept(grid, key) / "trials" / key / "train"
        rows = load_csv(train / "human.csv")
        human = build_human(f"synthetic:{key.split('-')[0]}", cfg)
        gaps = []
        for episode in range(3):
            human.reset()
            mine = rows.episode == episode
            for o, a, t in zip(rows.obs[mine].astype(float), rows.actions[mine], rows.time_s[mine], strict=True):
                pad = None
                if o[14] >= 0:
                    u, v, r = o[12] * (w / 2) + (w - 1) / 2, o[13] * (h / 2) + (h - 1) / 2, o[14] * (h / 2)
                    pad = PadDetection(u, v, r, bool(u - r < 0 or u + r > w - 1 or v - r < 0 or v + r > h - 1))
                obs = Observation(tuple(o[0:3] * 10), tuple(o[3:6] * np.pi), tuple(o[6:9] * 5), tuple(o[9:12] * np.pi),
                                  pad, (w, h), int(round(t * 1000)))
                gaps.append(float(np.linalg.norm(human.read(obs).command.to_array() - a)))
        final, _ = load_checkpoint(train / "checkpoints" / f"episode_{int(key.split('-')[2]) - 1:03d}.npz")
        policy_gap = np.linalg.norm(final.act(rows.obs) - rows.actions, axis=1)
        line = {"key": key, "grid": grid, "replayed_steps": len(gaps),
                "teacher_gap_mean": round(float(np.mean(gaps)), 5), "teacher_gap_max": round(float(np.max(gaps)), 5),
                "teacher_exact_share": round(float(np.mean(np.array(gaps) < 1e-3)), 4),
                "policy_gap_on_training_mean": round(float(policy_gap.mean()), 5), "training_rows": len(rows.obs)}
        with out.open("a") as fh:
            fh.write(json.dumps(line) + "\n")
        print(line, flush=True)


# ----- the analysis ---------------------------------------------------------------------------------
BOOT = 10_000  # paired bootstrap resamples over participants, seed 0
KINDS = ("landed", "off_pad", "timeout", "fence")


def wilson(k: int, n: int, z: float = 1.959964) -> list[float]:
    """Wilson's 95 % score interval of k successes in n, in percent."""
    import math

    if n == 0:
        return [math.nan, math.nan]
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return [round(100 * (centre - half), 2), round(100 * (centre + half), 2)]


def _episodes(grid: str, name: str) -> list[dict] | None:
    path = HERE / "episodes" / grid / f"{name}.jsonl"
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()] if path.exists() else None


def _pool(cells: list[dict]) -> dict:
    """Cells of steps pooled, weighted by their steps."""
    n = sum(c["n"] for c in cells)
    ni = sum(c["intent_n"] for c in cells)

    def w(field: str, count: str = "n"):
        total = sum(c[count] for c in cells if c[field] is not None)
        return None if total == 0 else round(sum(c[field] * c[count] for c in cells if c[field] is not None) / total, 4)

    axes = None
    if n:
        axes = [round(sum(c["gap_abs"][a] * c["n"] for c in cells if c["n"]) / n, 4) for a in range(4)]
    return {"steps": n, "gap_norm": w("gap_norm"), "gap_abs": axes, "intent_gap_norm": w("intent_gap_norm", "intent_n"),
            "intent_steps": ni, "nn": w("nn"), "override_share": None if n == 0 else round(sum(c["override"] for c in cells) / n, 4)}


def policy_summary(eps: list[dict]) -> dict:
    """Endpoints 1-3 of one policy from its episodes."""
    import numpy as np

    n = len(eps)
    out: dict = {"starts": n}
    for kind in KINDS:
        k = sum(e["kind"] == kind for e in eps)
        out[kind] = {"count": k, "pct": round(100 * k / n, 2), "wilson95": wilson(k, n)}
    off = [e["touchdown_distance_m"] for e in eps if e["kind"] == "off_pad"]
    out["off_pad_distance_m"] = None if not off else {"median": round(float(np.median(off)), 3),
                                                      "min": min(off), "max": max(off)}
    for kind in ("timeout", "fence"):
        close = [e["closest_approach_m"] for e in eps if e["kind"] == kind]
        out[f"{kind}_closest_approach_m"] = None if not close else {"median": round(float(np.median(close)), 3),
                                                                      "min": min(close), "max": max(close)}
    failed = [e for e in eps if not e["success"]]
    out["failures_by_end_phase"] = {p: sum(e["end_phase"] == p for e in failed) for p in PHASES}
    out["failures_by_kind_and_end_phase"] = {k: {p: sum(e["kind"] == k and e["end_phase"] == p for e in failed)
                                                 for p in PHASES} for k in KINDS[1:]}
    timeouts = [e for e in eps if e["kind"] == "timeout"]
    out["timeout_phase_share"] = None if not timeouts else {
        p: round(float(np.mean([e["phase_steps"][p] / max(1, sum(e["phase_steps"].values())) for e in timeouts])), 4)
        for p in PHASES}
    out["teacher_by_phase"] = {p: _pool([e["by_phase"][p] for e in eps]) for p in PHASES}
    out["teacher_all"] = _pool([e["all"] for e in eps])
    out["teacher_memory"] = {m: _pool([e["by_memory"][m] for e in eps]) for m in ("remembered", "not")}
    out["teacher_memory_final_descent"] = {m: _pool([e["final_by_memory"][m] for e in eps]) for m in ("remembered", "not")}
    for label, group in (("landed", [e for e in eps if e["success"]]), ("failed", failed)):
        out[f"teacher_{label}_by_phase"] = {p: _pool([e["by_phase"][p] for e in group]) for p in PHASES}
        out[f"teacher_{label}"] = _pool([e["all"] for e in group])
    out["mode_share"] = {m: round(sum(e["mode_steps"][m] for e in eps) / max(1, sum(sum(e["mode_steps"].values()) for e in eps)), 4)
                         for m in MODES}
    return out


def _boot(values: dict[str, tuple[float, float]], seed: int = 0) -> dict:
    """Pooled CoL and Demo means over participants and their paired difference, with percentile
    intervals from BOOT resamples of participants (each resample keeps a participant's pair)."""
    import numpy as np

    names = sorted(values)
    col = np.array([values[k][0] for k in names], float)
    demo = np.array([values[k][1] for k in names], float)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(names), size=(BOOT, len(names)))

    def ci(x):
        sample = np.nanmean(x[idx], axis=1)
        return [round(float(np.nanpercentile(sample, 2.5)), 3), round(float(np.nanpercentile(sample, 97.5)), 3)]

    return {"participants": len(names), "col": round(float(np.nanmean(col)), 3), "col_ci95": ci(col),
            "demo": round(float(np.nanmean(demo)), 3), "demo_ci95": ci(demo),
            "col_minus_demo": round(float(np.nanmean(col - demo)), 3), "col_minus_demo_ci95": ci(col - demo)}


def mcnemar(a: list[bool], b: list[bool]) -> dict:
    """Exact McNemar test of two policies flown on the same starts (b landed where a did not, and
    the reverse)."""
    from scipy.stats import binomtest

    gained = sum((not x) and y for x, y in zip(a, b, strict=True))
    lost = sum(x and not y for x, y in zip(a, b, strict=True))
    p = 1.0 if gained + lost == 0 else binomtest(min(gained, lost), gained + lost, 0.5).pvalue
    return {"landed": sum(b), "final_landed": sum(a), "gained": gained, "lost": lost, "p_exact": round(float(p), 4)}


MIN_GROUP = 5  # a policy enters the failed-against-landed comparison with at least 5 of each


def failed_vs_landed(eps: list[dict]) -> dict | None:
    """Within one policy: the failed episodes' steps against the landed ones', by phase (the
    teacher's gap, the nearest-neighbour distance) and the share of final-descent steps on which
    the teacher acts from memory."""
    failed = [e for e in eps if not e["success"]]
    landed = [e for e in eps if e["success"]]
    if len(failed) < MIN_GROUP or len(landed) < MIN_GROUP:
        return None
    out = {}
    for label, group in (("landed", landed), ("failed", failed)):
        final = _pool([e["by_phase"]["final"] for e in group])
        approach = _pool([e["by_phase"]["approach"] for e in group])
        memory = _pool([e["final_by_memory"]["remembered"] for e in group])
        not_memory = _pool([e["final_by_memory"]["not"] for e in group])
        out[label] = {"episodes": len(group), "gap_approach": approach["gap_norm"], "gap_final": final["gap_norm"],
                      "nn_approach": approach["nn"], "nn_final": final["nn"],
                      "gap_final_memory": memory["gap_norm"], "gap_final_not_memory": not_memory["gap_norm"],
                      "final_memory_share": None if not final["steps"] else round(memory["steps"] / final["steps"], 4),
                      "override_final": final["override_share"], "override_approach": approach["override_share"]}
    return out


def _boot_one(values: list[float], seed: int = 0) -> dict:
    import numpy as np

    x = np.array(values, float)
    idx = np.random.default_rng(seed).integers(0, len(x), size=(BOOT, len(x)))
    sample = x[idx].mean(axis=1)
    return {"policies": len(x), "mean": round(float(x.mean()), 4),
            "ci95": [round(float(np.percentile(sample, 2.5)), 4), round(float(np.percentile(sample, 97.5)), 4)]}


def summarise() -> None:
    """summary.json (every figure of endpoints 1-4 so far) and table.md from the committed raw files."""
    import numpy as np

    done = verdicts()
    summary: dict = {"verify": {k: v["verdict"] for k, v in done.items()}, "policies": {}, "pooled": {}, "stability": {}}
    per: dict = {}
    for grid, key in POLICIES:
        eps = _episodes(grid, key)
        if eps is None:
            continue
        s = policy_summary(eps)
        s["same_as_evaluation"] = sum(e.get("same_as_evaluation", False) for e in eps)
        summary["policies"][key] = s
        per[key] = s
    metrics = {
        "landed_pct": lambda s: s["landed"]["pct"], "off_pad_pct": lambda s: s["off_pad"]["pct"],
        "timeout_pct": lambda s: s["timeout"]["pct"], "fence_pct": lambda s: s["fence"]["pct"],
        "gap_norm_all": lambda s: s["teacher_all"]["gap_norm"],
        "gap_norm_search": lambda s: s["teacher_by_phase"]["search"]["gap_norm"],
        "gap_norm_approach": lambda s: s["teacher_by_phase"]["approach"]["gap_norm"],
        "gap_norm_final": lambda s: s["teacher_by_phase"]["final"]["gap_norm"],
        "gap_norm_memory": lambda s: s["teacher_memory"]["remembered"]["gap_norm"],
        "gap_norm_not_memory": lambda s: s["teacher_memory"]["not"]["gap_norm"],
        "gap_norm_final_memory": lambda s: s["teacher_memory_final_descent"]["remembered"]["gap_norm"],
        "gap_norm_final_not_memory": lambda s: s["teacher_memory_final_descent"]["not"]["gap_norm"],
        "gap_norm_landed": lambda s: s["teacher_landed"]["gap_norm"],
        "gap_norm_failed": lambda s: s["teacher_failed"]["gap_norm"],
        "nn_all": lambda s: s["teacher_all"]["nn"], "nn_landed": lambda s: s["teacher_landed"]["nn"],
        "nn_failed": lambda s: s["teacher_failed"]["nn"],
        "nn_search": lambda s: s["teacher_by_phase"]["search"]["nn"],
        "nn_approach": lambda s: s["teacher_by_phase"]["approach"]["nn"],
        "nn_final": lambda s: s["teacher_by_phase"]["final"]["nn"],
        "memory_share": lambda s: s["mode_share"]["remembered"],
        "override_share": lambda s: s["teacher_all"]["override_share"],
        "override_share_failed": lambda s: s["teacher_failed"]["override_share"],
        "override_share_landed": lambda s: s["teacher_landed"]["override_share"],
    }
    for grid, people in GRIDS.items():
        pairs = [p for p in people if f"{p}-col-20-s0" in per and f"{p}-demo-20-s0" in per]
        if not pairs:
            continue
        pooled = {}
        for name, get in metrics.items():
            values = {p: tuple(np.nan if get(per[f"{p}-{c}-20-s0"]) is None else get(per[f"{p}-{c}-20-s0"])
                               for c in CONDITIONS) for p in pairs}
            pooled[name] = _boot(values)
        summary["pooled"][grid] = pooled
    summary["failed_vs_landed"] = {}
    for grid in GRIDS:
        within = {key: failed_vs_landed(_episodes(grid, key)) for g, key in POLICIES if g == grid and key in per}
        within = {k: v for k, v in within.items() if v is not None}
        if not within:
            continue
        figures = next(iter(within.values()))["landed"].keys() - {"episodes"}
        pooled = {}
        for name in sorted(figures):
            pairs = [(v["landed"][name], v["failed"][name]) for v in within.values()
                     if v["landed"][name] is not None and v["failed"][name] is not None]
            if pairs:
                pooled[name] = {"landed": _boot_one([a for a, _ in pairs]), "failed": _boot_one([b for _, b in pairs]),
                                "failed_minus_landed": _boot_one([b - a for a, b in pairs])}
        summary["failed_vs_landed"][grid] = {"policies": within, "pooled": pooled}
    for grid, key in POLICIES:
        final = _episodes(grid, key)
        record = HERE / "fit" / f"{key}.json"
        if final is None or not record.exists():
            continue
        landed = [e["success"] for e in final]
        entry = {"final": sum(landed), "fit": json.loads(record.read_text())}
        conv = _episodes(grid, f"{key}--converged")
        entry["converged"] = None if conv is None else mcnemar(landed, [e["success"] for e in conv])
        reseeds = []
        for seed in RESEEDS:
            eps = _episodes(grid, f"{key}--reseed-{seed}")
            if eps is not None:
                reseeds.append({"seed": seed, **mcnemar(landed, [e["success"] for e in eps])})
        entry["reseeds"] = reseeds
        if reseeds:
            rates = [r["landed"] for r in reseeds]
            entry["reseed_spread"] = {"min": min(rates), "max": max(rates), "sd": round(float(np.std(rates, ddof=1)), 2)
                                      if len(rates) > 1 else None}
        del entry["fit"]["episodes"]
        summary["stability"][key] = entry
    (HERE / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    (HERE / "table.md").write_text(table(summary))
    print((HERE / "table.md").read_text())


def _f(x, digits: int = 2) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def table(summary: dict) -> str:
    """The figures of summary.json as Markdown tables."""
    out = ["# The learner diagnosis: tables (made by `run.py summarise` from the committed raw files)", ""]
    out += ["## Reruns", "", "| policy | verdict |", "| --- | --- |"]
    out += [f"| {k} | {v.split(': ', 1)[1]} |" for k, v in summary["verify"].items()]
    out += ["", "## Endpoint 1: outcomes per policy (100 held-out starts; Wilson 95 % intervals)", "",
            "| policy | landed | off the pad | timeout | fence | off-pad distance, median (min-max) m | timeout closest approach, median m | records as the evaluation |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for key, s in summary["policies"].items():
        cells = [f"{s[k]['count']} [{s[k]['wilson95'][0]:.0f}, {s[k]['wilson95'][1]:.0f}]" for k in KINDS]
        off = s["off_pad_distance_m"]
        off_text = "-" if off is None else f"{off['median']:.2f} ({off['min']:.2f}-{off['max']:.2f})"
        to = s["timeout_closest_approach_m"]
        out.append(f"| {key} | " + " | ".join(cells) + f" | {off_text} | {'-' if to is None else _f(to['median'])} | "
                   f"{s['same_as_evaluation']}/{s['starts']} |")
    out += ["", "## Endpoint 2: where failures happen (phase of the last 2 s; timeouts: mean share of their steps)", "",
            "| policy | failures | search | approach | final descent | off pad: final descent | timeout steps: search / approach / final |",
            "| --- | ---: | ---: | ---: | ---: | ---: | --- |"]
    for key, s in summary["policies"].items():
        f = s["failures_by_end_phase"]
        ts = s["timeout_phase_share"]
        ts_text = "-" if ts is None else " / ".join(f"{100 * ts[p]:.0f} %" for p in PHASES)
        out.append(f"| {key} | {sum(f.values())} | {f['search']} | {f['approach']} | {f['final']} | "
                   f"{s['failures_by_kind_and_end_phase']['off_pad']['final']} | {ts_text} |")
    out += ["", "## Endpoint 3: the teacher in the policy's shadow (mean action gap, norm of the 4 sticks; nearest-neighbour distance to the training observations)", "",
            "| policy | gap all | search | approach | final | memory / not (all) | memory / not (final descent) | memory share | gap landed / failed | NN landed / failed | NN search / approach / final | teacher would hold the override: landed / failed |",
            "| --- | ---: | ---: | ---: | ---: | --- | --- | ---: | --- | --- | --- | --- |"]
    for key, s in summary["policies"].items():
        ph, mem, memf = s["teacher_by_phase"], s["teacher_memory"], s["teacher_memory_final_descent"]
        out.append(f"| {key} | {_f(s['teacher_all']['gap_norm'], 3)} | {_f(ph['search']['gap_norm'], 3)} | "
                   f"{_f(ph['approach']['gap_norm'], 3)} | {_f(ph['final']['gap_norm'], 3)} | "
                   f"{_f(mem['remembered']['gap_norm'], 3)} / {_f(mem['not']['gap_norm'], 3)} | "
                   f"{_f(memf['remembered']['gap_norm'], 3)} / {_f(memf['not']['gap_norm'], 3)} | "
                   f"{100 * s['mode_share']['remembered']:.1f} % | "
                   f"{_f(s['teacher_landed']['gap_norm'], 3)} / {_f(s['teacher_failed']['gap_norm'], 3)} | "
                   f"{_f(s['teacher_landed']['nn'], 3)} / {_f(s['teacher_failed']['nn'], 3)} | "
                   f"{_f(ph['search']['nn'], 3)} / {_f(ph['approach']['nn'], 3)} / {_f(ph['final']['nn'], 3)} | "
                   f"{_f(s['teacher_landed']['override_share'], 3)} / {_f(s['teacher_failed']['override_share'], 3)} |")
    for grid, pooled in summary["pooled"].items():
        out += ["", f"## Pooled: {grid} (mean over participants; 95 % paired bootstrap over participants, {BOOT:,} resamples)", "",
                "| figure | CoL | Demo | CoL - Demo |", "| --- | --- | --- | --- |"]
        for name, b in pooled.items():
            out.append(f"| {name} | {b['col']:.3f} [{b['col_ci95'][0]:.3f}, {b['col_ci95'][1]:.3f}] | "
                       f"{b['demo']:.3f} [{b['demo_ci95'][0]:.3f}, {b['demo_ci95'][1]:.3f}] | "
                       f"{b['col_minus_demo']:+.3f} [{b['col_minus_demo_ci95'][0]:+.3f}, {b['col_minus_demo_ci95'][1]:+.3f}] |")
    for grid, block in summary["failed_vs_landed"].items():
        out += ["", f"## Failed against landed episodes within a policy: {grid} (policies with at least {MIN_GROUP} of each: "
                f"{', '.join(block['policies'])}; mean over them, 95 % bootstrap over policies)", "",
                "| figure | landed | failed | failed - landed |", "| --- | --- | --- | --- |"]
        for name, b in block["pooled"].items():
            out.append(f"| {name} ({b['landed']['policies']}) | {b['landed']['mean']:.3f} [{b['landed']['ci95'][0]:.3f}, {b['landed']['ci95'][1]:.3f}] | "
                       f"{b['failed']['mean']:.3f} [{b['failed']['ci95'][0]:.3f}, {b['failed']['ci95'][1]:.3f}] | "
                       f"{b['failed_minus_landed']['mean']:+.3f} [{b['failed_minus_landed']['ci95'][0]:+.3f}, {b['failed_minus_landed']['ci95'][1]:+.3f}] |")
    if summary["stability"]:
        out += ["", "## Endpoint 4: converged and reseeded policies against the final one (landed of 100, paired by start; exact McNemar)", "",
                "| policy | final | converged (gained / lost, p) | reseeded 1-5 (p against the final) | reseed spread | converged at update | held-out loss | loss_all final / converged |",
                "| --- | ---: | --- | --- | --- | ---: | ---: | --- |"]
        for key, e in summary["stability"].items():
            c = e["converged"]
            conv = "-" if c is None else f"{c['landed']} (+{c['gained']} / -{c['lost']}, p {c['p_exact']:.3f})"
            rs = ", ".join(f"{r['landed']} (p {r['p_exact']:.3f})" for r in e["reseeds"]) or "-"
            spread = e.get("reseed_spread")
            fit = e["fit"]
            out.append(f"| {key} | {e['final']} | {conv} | {rs} | "
                       f"{'-' if not spread else str(spread['min']) + '-' + str(spread['max'])} | "
                       f"{fit['converged']['best_update']} | {fit['converged']['held_out_loss']:.5f} | "
                       f"{fit['final']['loss_all']:.5f} / {fit['converged']['loss_all']:.5f} |")
    return "\n".join(out) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("step", choices=("code", "verify", "fly", "teacher-check", "fit", "summarise"))
    parser.add_argument("keys", nargs="*", help="policies (e.g. P1-col-20-s0); default: all 24")
    parser.add_argument("--commit", default="HEAD", help="step code: the commit to export (default HEAD)")
    args = parser.parse_args()
    if args.step == "code":
        export_code(args.commit)
        return
    if not (CODE / "COMMIT").exists():
        raise SystemExit(f"run the step 'code' first: {_rel(CODE)} is missing")
    os.chdir(CODE)  # the experiment files and committed grids as the export holds them
    if args.step == "verify":
        verify(args.keys)
    elif args.step == "fly":
        fly(args.keys)
    elif args.step == "teacher-check":
        teacher_check(args.keys)
    elif args.step == "fit":
        fit(args.keys)
    else:
        summarise()


if __name__ == "__main__":
    main()
