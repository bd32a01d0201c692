"""Policies trained in our SITL matched to PX4 SIH, flown on PX4 SIH. The plan is docs/camera.md,
"Policies trained in our SITL matched to PX4 SIH (preregistration)", written before any of these
runs. Steps, each resumable (what is kept is not run again):

    python results/transfer/matched-trained/run.py config     # config.toml: the grid's 16 trials in the matched SITL
    python results/transfer/matched-trained/run.py teacher    # the drift-judging expert on the 20 held-out starts there
    python results/transfer/matched-trained/run.py train      # col experiment: the 16 trials; checkpoints/ and grid/ kept
    python results/transfer/matched-trained/run.py fly        # each policy on a freshly started PX4 SIH at 4x, 20 starts
    python results/transfer/matched-trained/run.py summarise  # summary.json and table.md

``--policies KEY,...`` narrows ``fly`` (``--episodes N``: a check, kept under the runs folder's
checks/). Run folders go to runs/transfer-matched-trained/ (``--runs`` for another); what is
committed is the config, the grid's records (grid/), the final checkpoints, each evaluation's
episodes (episodes/) and the summaries.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
from pathlib import Path
from typing import Any

from colcommon.logged_run import run_logged
from colcommon.script_module import load_script

HERE = Path(__file__).resolve().parent
TRANSFER = HERE.parent
ROOT = HERE.parents[2]
CONFIG = HERE / "config.toml"
CHECKPOINTS, EPISODES, GRID = HERE / "checkpoints", HERE / "episodes", HERE / "grid"
DEFAULT_RUNS = ROOT / "runs" / "transfer-matched-trained"
MATCHED_CONFIG = TRANSFER / "matched" / "configs" / "ours-matched-still.toml"
GRID_FILES = ("results.jsonl", "config.toml", "experiment.json", "environment.jsonl", "timings.jsonl")
GRID_LINES = {  # the pinned grid's [experiment] narrowed to the transfer table's 16 trials
    'conditions = ["demo", "int", "col"]': 'conditions = ["demo", "col"]',
    "interactions = [4, 8, 12, 20]": "interactions = [20]",
    "seeds = [0, 1, 2, 3]": "seeds = [0, 1]",
}
DRIFT_JUDGING_PILOT = """
[companion.pilot]  # the participants' expert judges the drift from the picture (the on-craft plan's Amendment 2)
set_down_by_picture = true
judge_drift_by_picture = true
"""
TEACHER = ("--pilot", "expert", "--condition", "demo", "--no-learn")

T = load_script(TRANSFER / "run.py", "transfer_run")  # the table's own: policies, starts, autopilots
M = load_script(TRANSFER / "matched" / "run.py", "matched_run")  # Amendment 2's: paths and the col command
_rel, col = M._rel, M.col


def record(step: str, **context: object) -> None:
    from colcommon.numeric_env import append_record

    append_record(HERE, step=step, command=["results/transfer/matched-trained/run.py", step], **context)


# ----- the config ---------------------------------------------------------------------------------

def config_text(matched: str) -> str:
    """Amendment 2's ours-matched config (the pinned grid's at level 0, the pad on the ground,
    PX4 SIH's fitted estimate error and response) with the grid narrowed to the 16 trials and the
    drift-judging participants."""
    text = matched
    for old, new in GRID_LINES.items():
        if text.count(old) != 1:
            raise SystemExit(f"{_rel(MATCHED_CONFIG)}: expected one line starting {old!r}; the plan's grid has changed")
        text = text.replace(old, new)
    if "[companion.pilot]" in text:
        raise SystemExit(f"{_rel(MATCHED_CONFIG)} already has a [companion.pilot] table")
    return ("# Policies trained in our SITL matched to PX4 SIH (docs/camera.md): the transfer table's 16 trials.\n"
            + text + DRIFT_JUDGING_PILOT)


def write_config() -> None:
    CONFIG.write_text(config_text(MATCHED_CONFIG.read_text()))
    print(f"wrote {_rel(CONFIG)}")
    record("config")


def need_config() -> None:
    if not CONFIG.exists():
        raise SystemExit(f"{_rel(CONFIG)} is missing: run.py config first")


# ----- the teacher and the training ---------------------------------------------------------------

def teacher(runs: Path) -> None:
    """The drift-judging expert on the 20 held-out starts in the matched SITL (described, not an endpoint)."""
    need_config()
    kept = EPISODES / "teacher-matched-sitl.jsonl"
    if kept.exists():
        return
    run_dir = runs / "teacher"
    shutil.rmtree(run_dir, ignore_errors=True)
    run_logged([col(), "fly", *TEACHER, "--config", _rel(CONFIG), "--episodes", str(T.EPISODES_EACH),
                "--seed", str(T.FIRST_SEED), "--run-dir", _rel(run_dir), "--no-pictures"], runs / "teacher.log", ROOT)
    EPISODES.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(run_dir / "episodes.jsonl", kept)
    record("teacher")
    print(json.dumps({"teacher_on_pad": on_pad(kept)}), flush=True)


def train(runs: Path, workers: int) -> None:
    """``col experiment`` on config.toml (it resumes a partly run grid by itself); then the grid's
    records, each trial's final checkpoint and its evaluation in the matched SITL are kept."""
    need_config()
    out = runs / "grid"
    # col named relative to the repository: the experiment records its command line in
    # environment.jsonl, which is committed (grid/)
    run_logged([_rel(Path(col())), "experiment", "--config", _rel(CONFIG), "--workers", str(workers), "--out", _rel(out)],
               runs / "train.log", ROOT)
    GRID.mkdir(parents=True, exist_ok=True)
    for name in GRID_FILES:
        if (out / name).exists():
            shutil.copyfile(out / name, GRID / name)
    CHECKPOINTS.mkdir(parents=True, exist_ok=True)
    EPISODES.mkdir(parents=True, exist_ok=True)
    for line in (out / "results.jsonl").read_text().splitlines():
        result = json.loads(line)
        key = result["trial"]["key"]
        if result["status"] != "ok":
            print(f"{key}: {result['status']} ({result['error']}); not kept", flush=True)
            continue
        shutil.copyfile(out / result["final_checkpoint"], CHECKPOINTS / f"{key}.npz")
        shutil.copyfile(out / "trials" / key / "eval_episodes.jsonl", EPISODES / f"{key}-matched-sitl.jsonl")
    record("train", workers=workers)


# ----- flying on PX4 SIH --------------------------------------------------------------------------

def kept_path(key: str, episodes: int, runs: Path) -> Path:
    name = f"{key}-px4-still.jsonl"
    return EPISODES / name if episodes == T.EPISODES_EACH else runs / "checks" / f"{episodes}-{name}"


def fly(keys: tuple[str, ...], episodes: int, runs: Path) -> None:
    """Each policy alone on a freshly started PX4 SIH at 4x, the table's still-air config (the
    pad on the ground, where these policies learned it)."""
    for key in keys:
        kept, checkpoint = kept_path(key, episodes, runs), CHECKPOINTS / f"{key}.npz"
        if kept.exists():
            continue
        if not checkpoint.exists():
            print(f"{key}: no checkpoint (run.py train first); skipped", flush=True)
            continue
        run_dir = runs / f"{key}-px4-still-{episodes}"
        shutil.rmtree(run_dir, ignore_errors=True)
        cmd = [col(), "eval", _rel(checkpoint), "--episodes", str(episodes), "--seed", str(T.FIRST_SEED),
               "--config", _rel(T.config_path("px4", "still")), "--run-dir", _rel(run_dir)]
        T.fly_real("px4", cmd, runs / f"{key}-px4-still-{episodes}.log", runs / "autopilots" / key)
        kept.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(run_dir / "episodes.jsonl", kept)
        if kept.parent == EPISODES:
            record("fly", policy=key)
        print(json.dumps({"policy": key, "episodes": episodes, "on_pad": on_pad(kept)}), flush=True)


# ----- the analysis -------------------------------------------------------------------------------

def on_pad(path: Path) -> int:
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return sum(bool(r["success"]) for r in records)


def share_pct(path: Path, first: int = T.EPISODES_EACH) -> float | None:
    """% on the pad over the first ``first`` episodes (the held-out starts from seed 100000)."""
    if not path.exists():
        return None
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()][:first]
    return 100.0 * sum(bool(r["success"]) for r in records) / len(records) if records else None


def shares() -> dict[str, float | None]:
    s: dict[str, float | None] = {}
    for key in T.POLICIES:
        s[f"{key}/px4"] = share_pct(EPISODES / f"{key}-px4-still.jsonl")
        s[f"{key}/matched-sitl"] = share_pct(EPISODES / f"{key}-matched-sitl.jsonl")
        s[f"{key}/matched-sitl-100"] = share_pct(EPISODES / f"{key}-matched-sitl.jsonl", first=100)
        s[f"{key}/plain-px4-aligned"] = share_pct(T.EPISODES / f"{key}-px4-aligned-still.jsonl")
    return s


def mean_ci(values: list[float]) -> dict[str, Any]:
    from companion.statistics import bootstrap_mean_ci

    ci = bootstrap_mean_ci(values) if len(values) >= 2 else None
    return {"policies": len(values), "mean_points": round(statistics.fmean(values), 2) if values else None,
            "interval95": [round(x, 2) for x in ci] if ci else None}


def contrasts(s: dict[str, float | None]) -> dict[str, Any]:
    """The plan's three analyses, paired by policy key (or by participant and replicate)."""
    def diffs(a: str, b: str, keys: tuple[str, ...]) -> list[float]:
        pairs = [(s[f"{k}/{a}"], s[f"{k}/{b}"]) for k in keys]
        return [x - y for x, y in pairs if x is not None and y is not None]

    out: dict[str, Any] = {}
    for cond in ("demo", "col", "all"):
        keys = tuple(k for k in T.POLICIES if cond == "all" or f"-{cond}-" in k)
        out[f"gain_of_training_matched/{cond}"] = mean_ci(diffs("px4", "plain-px4-aligned", keys))
        out[f"transfer_gap/{cond}"] = mean_ci(diffs("px4", "matched-sitl", keys))
    col_minus_demo = [s[f"{k}/px4"] - s[f"{k.replace('-col-', '-demo-')}/px4"]  # type: ignore[operator]
                      for k in T.POLICIES if "-col-" in k
                      if s[f"{k}/px4"] is not None and s[f"{k.replace('-col-', '-demo-')}/px4"] is not None]
    out["col_minus_demo/px4"] = mean_ci(col_minus_demo)
    return out


def table(s: dict[str, float | None], c: dict[str, Any], teacher_line: str) -> str:
    cols = ("matched-sitl", "matched-sitl-100", "px4", "plain-px4-aligned")
    lines = ["# Policies trained in our SITL matched to PX4 SIH", "",
             "Made by `python results/transfer/matched-trained/run.py summarise` from `episodes/` and the transfer "
             "table's `../episodes/` (px4-aligned, still air); the plan is docs/camera.md, \"Policies trained in our "
             "SITL matched to PX4 SIH\". On the pad by truth, % of the 20 held-out starts (matched-sitl-100: of the "
             "trial's 100).", "", teacher_line, "",
             "| policy | " + " | ".join(cols) + " |", "| --- |" + " ---: |" * len(cols)]
    for key in T.POLICIES:
        cells = [s[f"{key}/{col_}"] for col_ in cols]
        lines.append(f"| {key} | " + " | ".join("-" if v is None else f"{v:.0f}" for v in cells) + " |")
    lines += ["", "| contrast | policies | mean, points | 95 % BCa |", "| --- | ---: | ---: | --- |"]
    for name, row in c.items():
        ci = "-" if row["interval95"] is None else f"[{row['interval95'][0]}, {row['interval95'][1]}]"
        lines.append(f"| {name} | {row['policies']} | {row['mean_points']} | {ci} |")
    return "\n".join(lines) + "\n"


def summarise() -> None:
    s = shares()
    c = contrasts(s)
    teacher_file = EPISODES / "teacher-matched-sitl.jsonl"
    teacher_line = (f"The teacher (the drift-judging expert) in the matched SITL: {on_pad(teacher_file)} of "
                    f"{len(teacher_file.read_text().splitlines())} on the pad." if teacher_file.exists()
                    else "The teacher has not flown yet.")
    summary = {"shares_pct": s, "contrasts": c, "teacher": teacher_line,
               "plan": "docs/camera.md, Policies trained in our SITL matched to PX4 SIH"}
    flown = sum(v is not None for k, v in s.items() if k.endswith("/px4"))
    T.write_summary(HERE, summary, table(s, c, teacher_line), flown, len(T.POLICIES))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=Path, default=DEFAULT_RUNS, help="where run folders and logs go (not committed)")
    sub = parser.add_subparsers(dest="step", required=True)
    sub.add_parser("config", help="config.toml from the matched SITL's config").set_defaults(go=lambda a: write_config())
    sub.add_parser("teacher", help="the drift-judging expert in the matched SITL").set_defaults(go=lambda a: teacher(a.runs))
    p = sub.add_parser("train", help="the 16 trials (col experiment)")
    p.add_argument("--workers", type=int, default=2, help="trials at once (default 2)")
    p.set_defaults(go=lambda a: train(a.runs, a.workers))
    p = sub.add_parser("fly", help="each policy on PX4 SIH")
    p.add_argument("--policies", help="KEY,... (default: all 16)")
    p.add_argument("--episodes", type=int, default=T.EPISODES_EACH, help="held-out starts (default 20; else a check)")
    p.set_defaults(go=lambda a: fly(T.parse_keys(a.policies), a.episodes, a.runs))
    sub.add_parser("summarise", help="summary.json and table.md").set_defaults(go=lambda a: summarise())
    args = parser.parse_args()
    args.runs.mkdir(parents=True, exist_ok=True)
    args.go(args)


if __name__ == "__main__":
    main()
