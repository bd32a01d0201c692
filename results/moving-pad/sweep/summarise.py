"""The pad-speed sweep's figures from the kept episode records, by the plan in docs/baselines.md
("Where learning wins: the pad-speed sweep" and its Amendment 1, written before the runs). Writes
summary.json and table.md here and the plot results/moving-pad/sweep.png; works on whatever
subset of arms and speeds has run, and says what is missing.

    python results/moving-pad/sweep/summarise.py
"""

from __future__ import annotations

import json
import re
import statistics
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from companion.statistics import bootstrap_mean_ci, wilson_interval

HERE = Path(__file__).resolve().parent
EPISODES = HERE / "episodes"
PLOT = HERE.parent / "sweep.png"
SPEEDS = ("0", "0.25", "0.5", "0.75", "1.0", "1.5")  # as run.py names them
ARMS = {
    "precland-px4": "precland, PX4 (our SITL), ArUco pad",
    "precland-ardupilot": "precland, ArduPilot PLND, moving-target option, ArUco pad",
    "precland-px4-plain": "precland, PX4, colour pad (a check: nothing to see)",
    "precland-px4-disc": "precland, PX4 (our SITL), ArUco board in the colour pad",
    "precland-ardupilot-disc": "precland, ArduPilot PLND, moving-target option, ArUco board in the colour pad",
    "expert": "scripted expert, colour pad",
    "expert-lead": "leading expert (lead_moving_pad), colour pad",
}
# Amendment 4: on a real autopilot's SITL (20 starts, 0.5 and 1.0 m/s), scored by the SITL's truth
REAL_ARMS = {
    "precland-ardupilot-real": "precland, real ArduCopter, PLND with the moving-target option",
    "precland-px4-real": "precland, real PX4 SIH",
    "expert-lead-ardupilot-real": "leading expert, real ArduCopter",
    "expert-lead-px4-real": "leading expert, real PX4 SIH",
}
REAL_SPEEDS = ("0.5", "1.0")
# The precision-landing arms each pad's policies are asked against: the colour pad's against the
# first board's arms (the plan), the board inked into the pad's against the same pad (Amendment 3)
PRECLAND_FOR_PAD = {"colour": ("precland-px4", "precland-ardupilot"),
                    "aruco-disc": ("precland-px4-disc", "precland-ardupilot-disc")}
CONDITIONS = {"demo": "Demo@20", "col": "CoL@20", "colplus": "CoL+@20"}
PLANNED_CONDITIONS = ("demo", "col", "colplus")  # docs/baselines.md, Amendment 2
LEARNED_CONDITIONS = ("col", "colplus")  # the question's "CoL@20 (or CoL+@20)"
PADS = {"colour": "colour pad", "aruco": "ArUco pad (void as flown, RUN.md)",
        "aruco-disc": "ArUco board in the colour pad"}
VOID_PADS = ("aruco",)  # RUN.md: the board covers the disc, the policies' detector sees no pad on it
PARTICIPANTS = ("P1", "P2", "P3", "P4")
REPLICATES = (0, 1)
LANDS_PCT, PRECLAND_FAILS_PCT = 90.0, 50.0
POLICY_FILE = re.compile(r"(?P<key>(?P<p>P\d+)-(?P<cond>[a-z]+)-20-s(?P<rep>\d+))-speed-(?P<speed>[0-9.]+)-(?P<pad>colour|aruco-disc|aruco)")
ARM_FILE = re.compile(r"(?P<arm>[a-z0-9-]+?)-speed-(?P<speed>[0-9.]+)")


# ----- reading -------------------------------------------------------------------------------------

def read(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def scan(folder: Path) -> tuple[dict[str, dict[str, list[dict]]], dict[str, dict[str, dict[str, dict[str, list[dict]]]]]]:
    """The kept episodes: arms[speed][arm] (the real autopilots' arms among them) and
    policies[speed][condition][pad][trial key]."""
    arms: dict[str, dict[str, list[dict]]] = {}
    policies: dict[str, dict[str, dict[str, dict[str, list[dict]]]]] = {}
    for path in sorted(folder.glob("*.jsonl")) if folder.is_dir() else []:
        if m := POLICY_FILE.fullmatch(path.stem):
            cell = policies.setdefault(m["speed"], {}).setdefault(m["cond"], {}).setdefault(m["pad"], {})
            cell[m["key"]] = read(path)
        elif (m := ARM_FILE.fullmatch(path.stem)) and (m["arm"] in ARMS or m["arm"] in REAL_ARMS):
            arms.setdefault(m["speed"], {})[m["arm"]] = read(path)
    return arms, policies


# ----- figures -------------------------------------------------------------------------------------

def pct(x: float) -> float:
    return round(100.0 * x, 2)


def describe(records: list[dict], distance: str = "touchdown_distance_m") -> dict[str, Any]:
    """Success with a 95 % Wilson interval, outcomes (fence exits and timeouts among them),
    touchdown distance (median, p90; ``distance``: the record's field, the truth's on a real
    autopilot's SITL) and time to land (median, simulated s) over touchdowns."""
    n = len(records)
    wins = sum(1 for r in records if r["success"])
    outcomes: dict[str, int] = {}
    for r in records:
        outcomes[r["outcome"]] = outcomes.get(r["outcome"], 0) + 1
    down = [r for r in records if r["outcome"] == "touchdown" and r.get(distance) is not None]
    distances = sorted(float(r[distance]) for r in down)
    low, high = wilson_interval(wins, n)
    return {
        "episodes": n, "successes": wins,
        "success_rate_pct": pct(wins / n) if n else None,
        "wilson95_pct": [pct(low), pct(high)] if n else None,
        "outcomes": dict(sorted(outcomes.items())),
        "fence_exits": outcomes.get("fence", 0), "timeouts": outcomes.get("timeout", 0),
        "touchdown_distance_m_median": round(statistics.median(distances), 3) if distances else None,
        "touchdown_distance_m_p90": round(float(np.percentile(distances, 90)), 3) if distances else None,
        "time_to_land_s_median": round(statistics.median(float(r["sim_time_s"]) for r in down), 2) if down else None,
    }


def over_trials(rates_pct: list[float]) -> dict[str, Any]:
    """The mean of the trials' success rates with a 95 % BCa bootstrap interval over trials
    (companion.statistics.bootstrap_mean_ci, fixed seed). Trials all equal: the interval is that
    value (every resample's mean is); fewer than two trials: none."""
    if not rates_pct:
        return {"trials": 0, "mean_success_pct": None, "interval95_pct": None, "interval": None}
    mean = round(float(np.mean(rates_pct)), 2)
    if len(rates_pct) < 2:
        return {"trials": 1, "mean_success_pct": mean, "interval95_pct": None, "interval": None}
    if len(set(rates_pct)) == 1:
        return {"trials": len(rates_pct), "mean_success_pct": mean, "interval95_pct": [mean, mean],
                "interval": "all trials equal"}
    ci = bootstrap_mean_ci(rates_pct)
    return {"trials": len(rates_pct), "mean_success_pct": mean,
            "interval95_pct": [round(ci[0], 2), round(ci[1], 2)] if ci else None, "interval": "BCa" if ci else None}


def policy_cell(trials: dict[str, list[dict]]) -> dict[str, Any]:
    """One condition on one pad at one speed: over its trials, each trial's rate, and pooled."""
    each = {key: describe(recs)["success_rate_pct"] for key, recs in sorted(trials.items()) if recs}
    pooled = describe([r for recs in trials.values() for r in recs])
    return {**over_trials(list(each.values())), "each_success_rate_pct": each, "pooled": pooled}


def expected_trial_keys(condition: str) -> list[str]:
    return [f"{p}-{condition}-20-s{r}" for p in PARTICIPANTS for r in REPLICATES]


def missing(arms: dict, policies: dict) -> list[str]:
    """What the plan has that is not kept yet: arm x speed, and trial x pad x speed."""
    out = [f"{arm} at {s} m/s" for s in SPEEDS for arm in ARMS if arm not in arms.get(s, {})]
    out += [f"{arm} at {s} m/s" for s in REAL_SPEEDS for arm in REAL_ARMS if arm not in arms.get(s, {})]
    conditions = sorted(set(PLANNED_CONDITIONS) | {c for cells in policies.values() for c in cells})
    for s in SPEEDS:
        for cond in conditions:
            for pad in [p for p in PADS if p not in VOID_PADS]:
                have = policies.get(s, {}).get(cond, {}).get(pad, {})
                lack = [k for k in expected_trial_keys(cond) if k not in have]
                if lack:
                    out.append(f"{CONDITIONS.get(cond, cond)} on the {PADS[pad]} at {s} m/s: "
                               + ("all 8 trials" if len(lack) == 8 else ", ".join(lack)))
    return out


def summary(folder: Path = EPISODES) -> dict[str, Any]:
    arms, policies = scan(folder)
    speeds: dict[str, Any] = {}
    for s in SPEEDS:
        speeds[s] = {
            "arms": {arm: describe(recs) for arm, recs in arms.get(s, {}).items() if arm in ARMS},
            "real_arms": {arm: describe(recs, "true_touchdown_distance_m")
                          for arm, recs in arms.get(s, {}).items() if arm in REAL_ARMS},
            "policies": {cond: {pad: policy_cell(trials) for pad, trials in pads.items()}
                         for cond, pads in sorted(policies.get(s, {}).items())},
        }
    out = {"speeds": speeds, "missing": missing(arms, policies)}
    out["question"] = question(speeds)
    return out


# ----- the plan's question -------------------------------------------------------------------------

def _policy(block: dict, cond: str, pad: str) -> dict | None:
    cell = block["policies"].get(cond, {}).get(pad)
    return cell if cell and cell["trials"] else None


def learning_wins(speeds: dict[str, Any], cond: str, pad: str) -> dict[str, list[str]]:
    """Speeds where the condition's mean over trials on ``pad`` is >= 90 % while both precland
    arms that pad is asked against land <= 50 %; undecided: speeds lacking one of the three."""
    yes, undecided = [], []
    arms = PRECLAND_FOR_PAD[pad]
    for s, block in speeds.items():
        pol = _policy(block, cond, pad)
        precland = [row for a in arms if (row := block["arms"].get(a)) and row["episodes"]]
        if pol is None or len(precland) < len(arms):
            undecided.append(s)
        elif pol["mean_success_pct"] >= LANDS_PCT and all(p["success_rate_pct"] <= PRECLAND_FAILS_PCT for p in precland):
            yes.append(s)
    return {"speeds": yes, "undecided": undecided}


def precland_better(speeds: dict[str, Any], arm: str, cond: str, pad: str) -> dict[str, list[str]]:
    """Speeds where the arm's Wilson interval lies wholly above the condition's interval over
    trials; undecided: either missing (or the policies with no interval)."""
    yes, undecided = [], []
    for s, block in speeds.items():
        pol, row = _policy(block, cond, pad), block["arms"].get(arm)
        if pol is None or pol["interval95_pct"] is None or row is None or not row["episodes"]:
            undecided.append(s)
        elif row["wilson95_pct"][0] > pol["interval95_pct"][1]:
            yes.append(s)
    return {"speeds": yes, "undecided": undecided}


def question(speeds: dict[str, Any]) -> dict[str, Any]:
    """Both halves of the question, for every condition and pad that has run."""
    conditions = sorted({c for b in speeds.values() for c in b["policies"]})
    pads = [pad for pad in PADS if pad not in VOID_PADS]
    wins = {f"{c}/{pad}": learning_wins(speeds, c, pad) for c in conditions if c in LEARNED_CONDITIONS for pad in pads}
    better = {f"{arm} over {c}/{pad}": precland_better(speeds, arm, c, pad)
              for pad in pads for arm in PRECLAND_FOR_PAD[pad] for c in conditions}
    return {"learning_wins": wins, "precland_better": better,
            "rule": f"learning wins: the condition's mean over its trials >= {LANDS_PCT:g} % while both precland arms "
                    f"land <= {PRECLAND_FAILS_PCT:g} %; precland better: its Wilson interval's low end above the "
                    "condition's interval's high end (95 % BCa over trials); the colour pad's policies against the "
                    "first board's precland arms, the board in the colour pad's against that board's (Amendment 3); "
                    "the policies' evaluations on the first ArUco pad are void as flown (RUN.md) and answer nothing"}


# ----- writing -------------------------------------------------------------------------------------

def _fmt(x: float | None, digits: int = 2) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def _cell(row: dict | None) -> str:
    return "-" if not row or not row.get("episodes") else f"{row['success_rate_pct']:.0f}"


def _policy_cell(cell: dict | None) -> str:
    if not cell or not cell["trials"]:
        return "-"
    return f"{cell['mean_success_pct']:.0f}" + ("" if cell["trials"] == 8 else f" ({cell['trials']} trials)")


def _arm_row(label: str, s: dict) -> str:
    ci = s["wilson95_pct"]
    outcomes = ", ".join(f"{k} {v}" for k, v in s["outcomes"].items())
    return (f"| {label} | {s['success_rate_pct']:.1f} % [{ci[0]:.1f}, {ci[1]:.1f}] ({s['successes']}/{s['episodes']}) "
            f"| {outcomes} | {_fmt(s['touchdown_distance_m_median'])} / {_fmt(s['touchdown_distance_m_p90'])} "
            f"| {_fmt(s['time_to_land_s_median'], 1)} | {s['fence_exits']} | {s['timeouts']} |")


def _policy_row(label: str, c: dict) -> str:
    ci, p = c["interval95_pct"], c["pooled"]
    over = f"{c['mean_success_pct']:.1f} %" + (f" [{ci[0]:.1f}, {ci[1]:.1f}]" if ci else " [no interval]")
    pooled = f"{p['success_rate_pct']:.1f} % [{p['wilson95_pct'][0]:.1f}, {p['wilson95_pct'][1]:.1f}]"
    return (f"| {label} | {over}, {c['trials']} trials | {pooled} ({p['successes']}/{p['episodes']}) "
            f"| {_fmt(p['touchdown_distance_m_median'])} / {_fmt(p['touchdown_distance_m_p90'])} "
            f"| {_fmt(p['time_to_land_s_median'], 1)} | {p['fence_exits']} | {p['timeouts']} |")


def _matrix(s: dict) -> list[str]:
    lines = ["| success %, by pad speed (m/s) | " + " | ".join(SPEEDS) + " |", "| --- |" + " ---: |" * len(SPEEDS)]
    for arm, label in ARMS.items():
        lines.append(f"| {label} | " + " | ".join(_cell(s["speeds"][v]["arms"].get(arm)) for v in SPEEDS) + " |")
    conditions = sorted({c for b in s["speeds"].values() for c in b["policies"]})
    for cond in conditions:
        for pad, pad_label in PADS.items():
            cells = [_policy_cell(s["speeds"][v]["policies"].get(cond, {}).get(pad)) for v in SPEEDS]
            lines.append(f"| {CONDITIONS.get(cond, cond)}, {pad_label} (mean of P1-P4 x 2) | " + " | ".join(cells) + " |")
    return lines


def _answers(q: dict) -> list[str]:
    lines = [f"Rule: {q['rule']}.", ""]
    for name, res in {**{f"learning wins, {k}": v for k, v in q["learning_wins"].items()},
                      **{f"precland better, {k}": v for k, v in q["precland_better"].items()}}.items():
        speeds = ", ".join(res["speeds"]) or "none"
        lines.append(f"- {name}: {speeds} m/s" + (f" (undecided, not all run: {', '.join(res['undecided'])})"
                                                    if res["undecided"] else ""))
    if not q["learning_wins"] and not q["precland_better"]:
        lines.append("- no policy has run yet: the question cannot be answered")
    return lines


def table(s: dict) -> str:
    lines = ["# The pad-speed sweep", "",
             "Made by `python results/moving-pad/sweep/summarise.py` from `episodes/`; the plan is docs/baselines.md, "
             "\"Where learning wins: the pad-speed sweep\", and its Amendment 1: the roof carries the multirotor at every "
             "speed, the expert is flown with and without `lead_moving_pad`, and every policy's teacher is the leading "
             "expert; Amendment 2 adds CoL+, Amendment 3 the ArUco board inked into the colour pad (`aruco-disc`). Success: touchdown on the roof within 0.5 m of the pad's centre; arms with a 95 % Wilson "
             "interval, policies as the mean over their trials with a 95 % BCa bootstrap interval over trials (and "
             "pooled with Wilson); distance and time among touchdowns.", "", *_matrix(s), "", "## The question", "",
             *_answers(s["question"]), ""]
    for speed, block in s["speeds"].items():
        if not block["arms"] and not block["policies"]:
            continue
        lines += [f"## Pad at {speed} m/s", "",
                  "| arm | success | outcomes | touchdown distance m, median / p90 | time to land s, median | fence exits | timeouts |",
                  "| --- | ---: | --- | ---: | ---: | ---: | ---: |"]
        lines += [_arm_row(ARMS[arm], block["arms"][arm]) for arm in ARMS if arm in block["arms"]]
        if block["policies"]:
            lines += ["", "| policies | success, mean over trials [95 % BCa] | pooled [95 % Wilson] | touchdown distance m, "
                      "median / p90 | time to land s, median | fence exits | timeouts |",
                      "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
            for cond, pads in block["policies"].items():
                lines += [_policy_row(f"{CONDITIONS.get(cond, cond)}, {PADS[pad]}", c) for pad, c in pads.items()]
        lines.append("")
    real = [(speed, arm, block["real_arms"][arm]) for speed, block in s["speeds"].items()
            for arm in REAL_ARMS if arm in block.get("real_arms", {})]
    if real:
        lines += ["## On the real autopilots' SITL (Amendment 4)", "",
                  "20 starts an arm and speed, the rendered camera, the board in the colour pad, the touchdown the SITL's "
                  "truth's first ground contact, success and distance by that truth (not part of the question).", "",
                  "| arm | pad speed m/s | success | outcomes | touchdown distance m (truth), median / p90 | time to land s, "
                  "median | fence exits | timeouts |", "| --- | ---: | ---: | --- | ---: | ---: | ---: | ---: |"]
        lines += [_arm_row(REAL_ARMS[arm], row).replace(" | ", f" | {speed} | ", 1) for speed, arm, row in real]
        lines.append("")
    lines += ["## Not run yet", ""] + ([f"- {m}" for m in s["missing"]] or ["- nothing: the sweep is complete"])
    return "\n".join(lines) + "\n"


def _series(s: dict) -> Iterable[tuple[str, list[float], list[float], list[tuple[float, float]], str]]:
    """(label, speeds, success %, (low, high) %, line style) of every arm and policy with data."""
    for arm, label in ARMS.items():
        pts = [(float(v), s["speeds"][v]["arms"][arm]) for v in SPEEDS if arm in s["speeds"][v]["arms"]]
        if pts:
            yield (label, [x for x, _ in pts], [r["success_rate_pct"] for _, r in pts],
                   [tuple(r["wilson95_pct"]) for _, r in pts], "-")
    conditions = sorted({c for b in s["speeds"].values() for c in b["policies"]})
    for cond in conditions:
        for pad, pad_label in PADS.items():
            if pad in VOID_PADS:
                continue
            cells = [(float(v), s["speeds"][v]["policies"].get(cond, {}).get(pad)) for v in SPEEDS]
            pts = [(x, c) for x, c in cells if c and c["trials"]]
            if pts:
                yield (f"{CONDITIONS.get(cond, cond)}, {pad_label} (mean over trials)", [x for x, _ in pts],
                       [c["mean_success_pct"] for _, c in pts],
                       [tuple(c["interval95_pct"] or (c["mean_success_pct"],) * 2) for _, c in pts],
                       "--" if pad == "aruco-disc" else ":")


def plot(s: dict, path: Path = PLOT) -> bool:
    """Success against pad speed, per arm (Wilson) and policy (BCa over trials). False: no data."""
    series = list(_series(s))
    if not series:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 5.5))
    for label, xs, ys, cis, style in series:
        err = np.array([[y - lo for y, (lo, _) in zip(ys, cis, strict=True)], [hi - y for y, (_, hi) in zip(ys, cis, strict=True)]])
        ax.errorbar(xs, ys, yerr=err, linestyle=style, marker="o", capsize=3, label=label)
    ax.set_xlabel("pad speed, m/s")
    ax.set_ylabel("success, % (95 % interval)")
    ax.set_xticks([float(v) for v in SPEEDS])
    ax.set_ylim(-3, 103)
    ax.set_title("The pad-speed sweep (docs/baselines.md, Amendments 1-3)")
    ax.legend(fontsize=7, loc="lower left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def main() -> None:
    s = summary()
    (HERE / "summary.json").write_text(json.dumps(s, indent=1) + "\n")
    (HERE / "table.md").write_text(table(s))
    written = ["summary.json", "table.md"] + (["../sweep.png"] if plot(s) else [])
    print(json.dumps({"written": written, "missing": len(s["missing"])}))


if __name__ == "__main__":
    main()
