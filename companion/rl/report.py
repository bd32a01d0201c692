"""The PPO grid's learning curves beside the paper's Figure 5 and our CoL result.

Reads run folders named ``a<actions>-s<seed>`` (``col ppo --out``; finished or still running:
``train_episodes.jsonl`` is written as episodes end), the random-policy runs and a CoL results
file of ``col experiment``, and writes ``summary.json`` and ``learning_curves.png``:

    python -m companion.rl.report results/ppo/grid --random results/ppo/random \\
        --col results/paper-grid/variants/native-skylakex/results.jsonl --out results/ppo
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
from pathlib import Path
from typing import Any

import numpy as np

from companion.rl.ppo import learning_curve

BLOCK = 50
PAPER_FIGURE_5 = {
    "ppo_2_actions": "100 % task completion after about 500 episodes (on average)",
    "ppo_3_actions": "less than 5 % after 1000 episodes",
    "ppo_4_actions": "fails (0 %) after 1000 episodes",
    "col_4_actions": "about 90 % in 20 episodes",
}
PAPER_ENDPOINTS = {2: (500, 1.0), 3: (1000, 0.05), 4: (1000, 0.0)}
"""(episode, completion) the paper's text gives for each PPO curve (Figure 5)."""
RUN_NAME = re.compile(r"^a(?P<actions>[234])-s(?P<seed>\d+)$")


TRAIN_LOG = "train_episodes.jsonl"


def read_episodes(folder: Path) -> list[dict[str, Any]]:
    """A run folder's training episodes so far (one JSON line each, written as episodes end)."""
    return [json.loads(line) for line in (folder / TRAIN_LOG).read_text().splitlines() if line.strip()]


def read_runs(grid: Path) -> dict[int, dict[int, list[dict[str, Any]]]]:
    """actions -> seed -> training episodes so far."""
    runs: dict[int, dict[int, list[dict[str, Any]]]] = {}
    for folder in sorted(grid.iterdir()):
        match = RUN_NAME.match(folder.name)
        if match and (folder / TRAIN_LOG).exists():
            runs.setdefault(int(match["actions"]), {})[int(match["seed"])] = read_episodes(folder)
    return runs


def curve_band(per_seed: dict[int, list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """Success rate per block of 50 training episodes: mean, min and max over the seeds that
    have finished the block."""
    curves = {seed: [b["success_rate"] for b in learning_curve(eps, size=BLOCK) if b["episodes"] == BLOCK]
              for seed, eps in per_seed.items()}
    longest = max((len(c) for c in curves.values()), default=0)
    band = []
    for k in range(longest):
        values = [c[k] for c in curves.values() if len(c) > k]
        band.append({"first_episode": k * BLOCK, "seeds": len(values), "mean": round(float(np.mean(values)), 4),
                     "min": min(values), "max": max(values)})
    return band


def final_evaluations(grid: Path) -> dict[str, Any]:
    """Each finished run's final policy on the held-out starts."""
    found = {}
    for path in sorted(grid.glob("a*-s*/results.json")):
        results = json.loads(path.read_text())
        found[path.parent.name] = {k: results["eval"][k] for k in ("episodes", "successes", "success_rate", "ci95",
                                                                    "touchdowns", "timeouts", "fence")}
        found[path.parent.name]["train_successes"] = results["train"]["successes"]
        found[path.parent.name]["train_wall_s"] = results["train"]["wall_s"]
    return found


def col_result(results_jsonl: Path, interactions: int = 20) -> dict[str, Any]:
    """CoL's held-out completion at ``interactions`` episodes, one value per finished trial
    (read as the experiment reads its results: a trial's first ``ok`` line counts)."""
    seen: dict[str, float] = {}
    for line in results_jsonl.read_text().splitlines():
        try:  # read here, not through companion.experiment (which builds on companion.rl)
            result = json.loads(line)
        except json.JSONDecodeError:  # a torn last line, as the experiment skips it
            continue
        t = result["trial"]
        if (result["status"] == "ok" and t["condition"] == "col" and t["interactions"] == interactions
                and t["key"] not in seen):
            seen[t["key"]] = result["eval_successes"] / result["eval_runs"]
    rates = list(seen.values())
    return {"interactions": interactions, "trials": len(rates),
            "success_rate_mean": round(statistics.fmean(rates), 4) if rates else None,
            "success_rate_sd": round(statistics.stdev(rates), 4) if len(rates) > 1 else None}


def random_results(folder: Path) -> dict[str, Any]:
    return {p.parent.name: json.loads(p.read_text())["summary"] for p in sorted(folder.glob("*/random.json"))}


def read_folders(folders: list[Path]) -> dict[int, list[dict[str, Any]]]:
    """Training episodes of named run folders, numbered 0, 1, ... (for an extra curve)."""
    return {k: read_episodes(f) for k, f in enumerate(folders)}


def summary(grid: Path, random_dir: Path | None, col_file: Path | None,
            extra: dict[str, list[Path]] | None = None) -> dict[str, Any]:
    runs = read_runs(grid)
    return {
        "extra_curves": {label: {"runs": [str(f) for f in folders], "curve": curve_band(read_folders(folders)),
                                 "training_episodes": [len(e) for e in read_folders(folders).values()],
                                 "training_successes": [sum(bool(r["success"]) for r in e)
                                                        for e in read_folders(folders).values()]}
                         for label, folders in (extra or {}).items()},
        "block_episodes": BLOCK,
        "training_episodes": {f"a{a}": {str(s): len(e) for s, e in seeds.items()} for a, seeds in sorted(runs.items())},
        "training_successes": {f"a{a}": {str(s): sum(bool(r["success"]) for r in e) for s, e in seeds.items()}
                               for a, seeds in sorted(runs.items())},
        "curves": {f"a{a}": curve_band(seeds) for a, seeds in sorted(runs.items())},
        "final_policies": final_evaluations(grid),
        "random_policy": random_results(random_dir) if random_dir else {},
        "col": col_result(col_file) if col_file else None,
        "paper_figure_5": PAPER_FIGURE_5,
    }


def plot(result: dict[str, Any], path: Path) -> None:
    """Mean and band of each action count's curve; the paper's endpoints and CoL beside them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(11, 4.5))
    colours = {2: "tab:blue", 3: "tab:orange", 4: "tab:green"}
    for actions, colour in colours.items():
        band = result["curves"].get(f"a{actions}", [])
        if band:
            x = np.array([b["first_episode"] + BLOCK for b in band])
            seeds = max(b["seeds"] for b in band)
            ax.plot(x, [100 * b["mean"] for b in band], color=colour, label=f"PPO {actions} actions, defaults (ours, {seeds} seed{'s' * (seeds > 1)})")
            ax.fill_between(x, [100 * b["min"] for b in band], [100 * b["max"] for b in band], color=colour, alpha=0.2)
        episode, rate = PAPER_ENDPOINTS[actions]
        ax.scatter([episode], [100 * rate], marker="*", s=160, color=colour, edgecolor="black",
                   label=f"paper: PPO {actions} actions", zorder=5)
    extra_colours = ("tab:purple", "tab:brown", "tab:pink", "tab:olive")  # each extra curve its own
    for k, (label, extra) in enumerate(result.get("extra_curves", {}).items()):
        band, colour = extra["curve"], extra_colours[k % len(extra_colours)]
        if band:
            x = np.array([b["first_episode"] + BLOCK for b in band])
            ax.plot(x, [100 * b["mean"] for b in band], color=colour, linestyle="--", label=label)
            ax.fill_between(x, [100 * b["min"] for b in band], [100 * b["max"] for b in band], color=colour, alpha=0.15)
    for rnd in result.get("random_policy", {}).values():
        ax.axhline(100 * rnd["success_rate"], color="grey", linestyle=":", linewidth=1,
                   label=f"uniformly random actions, {rnd['action_dims']} actions ({rnd['episodes']} episodes)")
    col = result.get("col")
    if col and col["success_rate_mean"] is not None:
        ax.scatter([20], [100 * col["success_rate_mean"]], marker="D", s=60, color="tab:red",
                   label=f"CoL 4 actions, 20 episodes (ours, {col['trials']} trials)", zorder=5)
    ax.scatter([20], [90], marker="*", s=160, color="tab:red", edgecolor="black", label="paper: CoL", zorder=5)
    ax.set(xlabel="training episodes", ylabel="task completion (%)", xlim=(0, 1050), ylim=(-3, 103),
           title="Landing: PPO on the sparse reward vs CoL (training success per 50 episodes; band: min-max over seeds)")
    ax.title.set_fontsize(9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _held_out(folder: Path, trained: int) -> str:
    """A run's policy on the held-out starts: the final one, else the last checkpoint's."""
    if (folder / "results.json").exists():
        ev, after = json.loads((folder / "results.json").read_text())["eval"], trained
    elif (folder / "checkpoint_eval.json").exists():
        flown = json.loads((folder / "checkpoint_eval.json").read_text())
        ev, after = flown["eval"], flown["train_episodes_seen"]
    else:
        return "not flown (unfinished)"
    lo, hi = ev["ci95"]
    median = ev.get("touchdown_distance_m_median")
    return (f"{ev['successes']}/{ev['episodes']} ({100 * lo:.0f}-{100 * hi:.0f} %); {ev['touchdowns']} touchdowns, "
            f"{ev['timeouts']} timeouts, {ev['fence']} fence exits" + (f"; median {median} m" if median is not None else "")
            + f" (policy after {after} episodes)")


def run_row(folder: Path, name: str) -> str:
    """One markdown table row of a PPO run folder: its settings, training outcomes, the median
    touchdown distance per block and successes per 100 episodes, and its held-out evaluation."""
    settings = json.loads((folder / "settings.json").read_text())
    episodes = read_episodes(folder) if (folder / TRAIN_LOG).exists() else []
    outcomes: dict[str, int] = {}
    for e in episodes:
        outcomes[e["outcome"]] = outcomes.get(e["outcome"], 0) + 1
    block = 200 if len(episodes) > 400 else 50
    medians = []
    for i in range(0, len(episodes), block):
        near = [e["touchdown_distance_m"] for e in episodes[i:i + block] if e["touchdown_distance_m"] is not None]
        medians.append(f"{statistics.median(near):.1f}" if near else "-")
    per_100 = [sum(bool(e["success"]) for e in episodes[i:i + 100]) for i in range(0, len(episodes), 100)]
    cells = [name, settings["action_dims"], settings["seed"], settings["log_std_init"],
             "yes" if settings.get("normalize_advantage", True) else "no", len(episodes),
             sum(bool(e["success"]) for e in episodes), ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items())),
             f"{', '.join(medians)} (per {block})", ", ".join(map(str, per_100)), _held_out(folder, len(episodes))]
    return "| " + " | ".join(str(c) for c in cells) + " |"


RUNS_HEADER = ("| run | actions | seed | initial log-std | advantages normalised | training episodes | training successes "
               "| training outcomes | median touchdown distance (m) | training successes per 100 episodes "
               "| policy on the held-out starts |\n" + "| --- " * 11 + "|")


def runs_table(root: Path, names: list[str]) -> str:
    """The markdown table of these run folders (paths relative to ``root``) of docs/baselines.md."""
    return "\n".join([RUNS_HEADER, *(run_row(root / name, name) for name in names)]) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("grid", type=Path, help="folder of a<actions>-s<seed> PPO runs")
    parser.add_argument("--random", type=Path, help="folder of random-policy runs (*/random.json)")
    parser.add_argument("--col", type=Path, help="results.jsonl of col experiment")
    parser.add_argument("--curve", action="append", default=[], metavar="LABEL=DIR,DIR,...",
                        help="an extra curve from these run folders (e.g. a sensitivity setting over seeds)")
    parser.add_argument("--table", nargs="+", default=[], metavar="RUN",
                        help="also write runs.md: a table of these run folders (relative to the grid's parent)")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    extra = {}
    for spec in args.curve:
        label, _, dirs = spec.partition("=")
        extra[label] = [Path(d) for d in dirs.split(",") if d]
    result = summary(args.grid, args.random, args.col, extra)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "summary.json").write_text(json.dumps(result, indent=1) + "\n")
    plot(result, args.out / "learning_curves.png")
    if args.table:
        (args.out / "runs.md").write_text(runs_table(args.grid.parent, args.table))
    print(json.dumps({k: result[k] for k in ("training_episodes", "training_successes", "final_policies")}))


if __name__ == "__main__":
    main()
