"""Our SITL matched to PX4 SIH: the transfer table's Amendment 2 (docs/camera.md), written before
any of these runs. Steps, each resumable (what is kept is not run again):

    python results/transfer/matched/run.py calibrate        # the expert on PX4 SIH and in our SITL: fit.json
    python results/transfer/matched/run.py configs          # the three columns' config files, from fit.json
    python results/transfer/matched/run.py fly ours-matched # the 16 policies x 20 held-out starts, one column
    python results/transfer/matched/run.py summarise        # summary.json and table.md

Columns: ours-ground (the pad on the ground), ours-est (and PX4 SIH's fitted estimate error),
ours-matched (and its fitted velocity response). ``--policies KEY,...`` narrows ``fly`` for a
check (``--episodes N``: kept under the runs folder's checks/). Run folders go to
runs/transfer-matched/ (``--runs`` for another); what is committed is each column's
episodes.jsonl (episodes/), the calibration's results and the summaries.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

from colcommon.logged_run import run_logged
from colcommon.script_module import load_script

HERE = Path(__file__).resolve().parent
TRANSFER = HERE.parent
ROOT = HERE.parents[2]
CONFIGS, EPISODES, CALIBRATION = HERE / "configs", HERE / "episodes", HERE / "calibration"
FIT = HERE / "fit.json"
DEFAULT_RUNS = ROOT / "runs" / "transfer-matched"
COLUMNS = ("ours-ground", "ours-est", "ours-matched")
EXPERT_EPISODES = 10
TAUS_S = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5)  # the candidate vel_cmd_tau_s (the plan's)
EXPERT = ("--pilot", "expert", "--condition", "demo", "--no-learn")
GROUND_PAD = """
[companion.session]
pad_ned_m = [0.0, 0.0, 0.0]  # the pad on the ground, as on the real autopilots

[sitl.world]
vehicle_height_m = 0.0
"""


T = load_script(TRANSFER / "run.py", "transfer_run")  # the table's own steps: its policies, seeds, configs, autopilots


def _rel(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(ROOT))
    except ValueError:
        return str(path)


def col() -> str:
    return str(Path(sys.executable).with_name("col"))


def record(step: str, **context: object) -> None:
    from colcommon.numeric_env import append_record

    append_record(HERE, step=step, command=["results/transfer/matched/run.py", step], **context)


# ----- configs ------------------------------------------------------------------------------------

def column_text(column: str, fit: dict[str, Any] | None) -> str:
    """A column's config: ``ours-still.toml`` (the grid's at level 0) with the pad on the ground,
    then (ours-est, ours-matched) the fitted ``[sitl.estimator]`` and (ours-matched) the
    ``[sitl.autopilot] vel_cmd_tau_s`` kept."""
    base = (TRANSFER / "configs" / "ours-still.toml").read_text()
    text = f"# The transfer table's Amendment 2 (docs/camera.md): {column}, still air.\n" + base + GROUND_PAD
    if column in ("ours-est", "ours-matched"):
        if fit is None:
            raise SystemExit(f"{_rel(FIT)} is missing: run.py calibrate first")
        est = fit["sitl_estimator"]
        text += "\n[sitl.estimator]  # fitted to PX4 SIH's estimate error (fit.json)\n" + "".join(
            f"{k} = {v}\n" for k, v in est.items())
    if column == "ours-matched":
        assert fit is not None
        text += f"\n[sitl.autopilot]  # fitted to PX4 SIH's velocity response (fit.json)\nvel_cmd_tau_s = {fit['vel_cmd_tau_s']}\n"
    return text


def config_path(column: str) -> Path:
    return CONFIGS / f"{column}-still.toml"


def tau_config_path(tau_s: float) -> Path:
    return CALIBRATION / f"ours-est-tau-{tau_s}.toml"


def write_configs() -> None:
    fit = json.loads(FIT.read_text()) if FIT.exists() else None
    CONFIGS.mkdir(parents=True, exist_ok=True)
    for column in COLUMNS:
        config_path(column).write_text(column_text(column, fit))
        print(f"wrote {_rel(config_path(column))}")
    record("configs")


# ----- calibration --------------------------------------------------------------------------------

def expert_command(config: Path, run_dir: Path) -> list[str]:
    return [col(), "fly", *EXPERT, "--config", _rel(config), "--episodes", str(EXPERT_EPISODES),
            "--seed", str(T.FIRST_SEED), "--run-dir", _rel(run_dir), "--no-pictures"]


def analyse(run_dir: Path, estimate: bool) -> dict[str, Any]:
    """The response of one expert run and (``estimate``: a real autopilot's, whose telemetry
    carries its truth) its estimate fit, by the two scripts that measure them."""
    fit = subprocess.run([sys.executable, str(HERE / "calibrate.py"), str(run_dir)], check=True,
                         capture_output=True, text=True, cwd=ROOT).stdout if estimate else ""
    tracks = subprocess.run([sys.executable, str(TRANSFER / "tracks.py"), str(run_dir)], check=True,
                            capture_output=True, text=True, cwd=ROOT).stdout.splitlines()
    episodes = [json.loads(line) for line in (run_dir / "episodes.jsonl").read_text().splitlines()]
    return {"estimate": json.loads(fit) if fit.strip() else None, "response": json.loads(tracks[-1])["response"],
            "on_pad": sum(bool(r["success"]) for r in episodes), "episodes": len(episodes)}


def gain_curve(response: dict[str, Any]) -> list[float]:
    return [row["horizontal_gain"] for row in response["by_lag"]]


def curve_distance(a: dict[str, Any], b: dict[str, Any]) -> float:
    """Sum of squared differences of two gain-at-lag curves (the plan's closeness)."""
    return float(sum((x - y) ** 2 for x, y in zip(gain_curve(a), gain_curve(b), strict=True)))


def calibrate(runs: Path) -> None:
    """The plan's calibration: the expert on PX4 SIH (fit of its estimate error, its response),
    then in our SITL with that error at each candidate lag; fit.json keeps the closest."""
    CALIBRATION.mkdir(parents=True, exist_ok=True)
    px4_file = CALIBRATION / "px4.json"
    if not px4_file.exists():
        run_dir = runs / "expert-px4"
        shutil.rmtree(run_dir, ignore_errors=True)
        T.fly_real("px4", expert_command(T.config_path("px4", "still"), run_dir), runs / "expert-px4.log",
                   runs / "autopilots" / "expert-px4")
        px4 = analyse(run_dir, estimate=True)
        shutil.copyfile(run_dir / "episodes.jsonl", CALIBRATION / "expert-px4.jsonl")
        px4_file.write_text(json.dumps(px4, indent=1) + "\n")
        record("calibrate-px4")
    px4 = json.loads(px4_file.read_text())
    estimator = px4["estimate"]["sitl_estimator"]
    tried: dict[str, Any] = {}
    for tau in TAUS_S:
        out = CALIBRATION / f"ours-tau-{tau}.json"
        if not out.exists():
            text = column_text("ours-est", {"sitl_estimator": estimator})
            tau_config_path(tau).write_text(text.replace("ours-est, still air", f"ours-est with vel_cmd_tau_s = {tau}")
                                            + f"\n[sitl.autopilot]\nvel_cmd_tau_s = {tau}\n")
            run_dir = runs / f"expert-ours-tau-{tau}"
            shutil.rmtree(run_dir, ignore_errors=True)
            run_logged(expert_command(tau_config_path(tau), run_dir), runs / f"expert-ours-tau-{tau}.log", ROOT)
            result = analyse(run_dir, estimate=False)
            shutil.copyfile(run_dir / "episodes.jsonl", CALIBRATION / f"expert-ours-tau-{tau}.jsonl")
            out.write_text(json.dumps(result, indent=1) + "\n")
        tried[str(tau)] = json.loads(out.read_text())
    distances = {tau: round(curve_distance(r["response"], px4["response"]), 4) for tau, r in tried.items()}
    best = min(distances, key=lambda k: (distances[k], float(k)))
    fit = {"sitl_estimator": estimator, "vel_cmd_tau_s": float(best), "curve_distance_by_tau": distances,
           "px4_response_best": px4["response"]["horizontal_best"],
           "ours_response_best_at_kept_tau": tried[best]["response"]["horizontal_best"],
           "px4_estimate": px4["estimate"]["pooled"],
           "expert_on_pad": {"px4": f"{px4['on_pad']}/{px4['episodes']}",
                             "ours_at_kept_tau": f"{tried[best]['on_pad']}/{tried[best]['episodes']}"},
           "plan": "docs/camera.md, the transfer table's Amendment 2"}
    FIT.write_text(json.dumps(fit, indent=1) + "\n")
    record("calibrate", kept_tau_s=float(best))
    print(json.dumps(fit))


# ----- the columns --------------------------------------------------------------------------------

def kept_path(key: str, column: str, episodes: int, runs: Path) -> Path:
    name = f"{key}-{column}-still.jsonl"
    return EPISODES / name if episodes == T.EPISODES_EACH else runs / "checks" / f"{episodes}-{name}"


def fly(column: str, keys: tuple[str, ...], episodes: int, runs: Path) -> None:
    if not config_path(column).exists():
        raise SystemExit(f"{_rel(config_path(column))} is missing: run.py configs first")
    for key in keys:
        kept = kept_path(key, column, episodes, runs)
        if kept.exists():
            continue
        run_dir = runs / f"{key}-{column}-{episodes}"
        shutil.rmtree(run_dir, ignore_errors=True)
        cmd = [col(), "eval", str(T.CHECKPOINTS / f"{key}.npz"), "--episodes", str(episodes), "--seed", str(T.FIRST_SEED),
               "--config", _rel(config_path(column)), "--run-dir", _rel(run_dir)]
        run_logged(cmd, runs / f"{key}-{column}-{episodes}.log", ROOT)
        kept.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(run_dir / "episodes.jsonl", kept)
        if kept.parent == EPISODES:
            record("fly", policy=key, column=column)
        records = [json.loads(line) for line in kept.read_text().splitlines()]
        print(json.dumps({"policy": key, "column": column, "episodes": len(records),
                          "on_pad": sum(bool(r["success"]) for r in records)}), flush=True)


# ----- the analysis -------------------------------------------------------------------------------

def summary() -> dict[str, Any]:
    """Per policy the share on the pad in each column; per column the signed prediction error
    (column - px4, still) and the reduction of the absolute error against ours-still, paired by
    policy, with 95 % BCa intervals over policies."""
    from companion.statistics import bootstrap_mean_ci

    def share(path: Path) -> float | None:
        return T.on_pad_pct(path)

    shares = {f"{k}/{c}": share(EPISODES / f"{k}-{c}-still.jsonl") for k in T.POLICIES for c in COLUMNS}
    shares |= {f"{k}/{c}": share(T.EPISODES / f"{k}-{c}-still.jsonl") for k in T.POLICIES for c in ("ours", "px4")}

    def mean_ci(values: list[float]) -> dict[str, Any]:
        ci = bootstrap_mean_ci(values) if len(values) >= 2 else None
        return {"policies": len(values), "mean_points": round(statistics.fmean(values), 2) if values else None,
                "interval95": [round(x, 2) for x in ci] if ci else None}

    columns: dict[str, Any] = {}
    for column in ("ours", *COLUMNS):
        rows = [(shares[f"{k}/{column}"], shares[f"{k}/px4"], shares[f"{k}/ours"]) for k in T.POLICIES]
        rows = [r for r in rows if None not in r]
        columns[column] = {"minus_px4": mean_ci([c - p for c, p, _ in rows]),
                           "absolute_error_reduction": mean_ci([abs(o - p) - abs(c - p) for c, p, o in rows])}
    return {"shares_pct": shares, "columns": columns, "plan": "docs/camera.md, the transfer table's Amendment 2"}


def table(s: dict[str, Any]) -> str:
    cols = ("ours", *COLUMNS, "px4")
    lines = ["# Our SITL matched to PX4 SIH", "", "Made by `python results/transfer/matched/run.py summarise` from "
             "`episodes/` and the transfer table's `../episodes/` (ours and px4, still air); the plan is docs/camera.md, "
             "the transfer table's Amendment 2. On the pad by truth, % of 20 episodes.", "",
             "| policy | " + " | ".join(cols) + " |", "| --- |" + " ---: |" * len(cols)]
    for key in T.POLICIES:
        cells = [s["shares_pct"][f"{key}/{c}"] for c in cols]
        lines.append(f"| {key} | " + " | ".join("-" if c is None else f"{c:.0f}" for c in cells) + " |")
    lines += ["", "| column | policies | column - px4, points | 95 % BCa | \\|ours - px4\\| - \\|column - px4\\| | 95 % BCa |",
              "| --- | ---: | ---: | --- | ---: | --- |"]
    for column, row in s["columns"].items():
        a, b = row["minus_px4"], row["absolute_error_reduction"]

        def ci(r: dict[str, Any]) -> str:
            return "-" if r["interval95"] is None else f"[{r['interval95'][0]}, {r['interval95'][1]}]"
        lines.append(f"| {column} | {a['policies']} | {a['mean_points']} | {ci(a)} | {b['mean_points']} | {ci(b)} |")
    return "\n".join(lines) + "\n"


def summarise() -> None:
    s = summary()
    flown = sum(v is not None for k, v in s["shares_pct"].items() if k.split("/")[1] in COLUMNS)
    T.write_summary(HERE, s, table(s), flown, len(T.POLICIES) * len(COLUMNS))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=Path, default=DEFAULT_RUNS, help="where run folders and logs go")
    sub = parser.add_subparsers(dest="step", required=True)
    sub.add_parser("calibrate", help="the expert on PX4 SIH and in our SITL: fit.json").set_defaults(
        go=lambda a: calibrate(a.runs))
    sub.add_parser("configs", help="the columns' config files").set_defaults(go=lambda a: write_configs())
    p = sub.add_parser("fly", help="the 16 policies in one column")
    p.add_argument("column", choices=COLUMNS)
    p.add_argument("--policies", help="KEY,... (default: the plan's 16)")
    p.add_argument("--episodes", type=episodes_count, default=T.EPISODES_EACH,
                   help="a check with fewer goes to the runs folder's checks/")
    p.set_defaults(go=lambda a: fly(a.column, T.parse_keys(a.policies), a.episodes, a.runs))
    sub.add_parser("summarise", help="summary.json and table.md").set_defaults(go=lambda a: summarise())
    args = parser.parse_args()
    args.go(args)


def episodes_count(text: str) -> int:
    n = int(text)
    if n < 1:
        raise argparse.ArgumentTypeError("--episodes must be at least 1")
    return n


if __name__ == "__main__":
    try:
        main()
    except subprocess.CalledProcessError as exc:
        raise SystemExit(str(exc)) from exc
