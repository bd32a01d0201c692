"""A bench before and after a change: two commits, each from a clean clone, run alternately.

Why alternately: a machine's speed drifts during a session (other jobs, thermal state), and runs
of one side in a row would carry that drift into the comparison. Each of ``--runs`` rounds runs
both sides, the side that goes first alternating, and each run's last JSON line is kept. The
summary gives, for every numeric figure whose name says it is a rate or a cost
(``steps_per_s``, ``cpu_ms_per_step``, ...), the median of each side and after / before, and
the median over rounds of each round's own after / before (``paired_after_over_before``): the
two runs of a round ran minutes apart, so the ratio within a round carries less of the
machine's drift than the ratio of the two sides' medians.

    python bench/ab.py BEFORE AFTER --bench rl_env_speed.py [--runs 3] [--out DIR] [-- ARGS...]
    python bench/ab.py BEFORE AFTER --bench rl_env_speed.py --from DIR   # the summary of kept lines

Both clones use this checkout's installed packages (``PYTHONPATH`` points at the clone). The
raw lines go to ``DIR/<before|after>-<bench>-<round>.json``; the summary is the last line printed.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FIGURES = ("steps_per_s", "cpu_ms_per_step", "episodes_per_core_s", "per_core_second", "ms_per_step")


def clone(commit: str, into: Path) -> Path:
    """A clean clone of ``commit`` (the repository as committed, nothing of the working tree)."""
    path = into / commit
    subprocess.run(["git", "clone", "-q", str(ROOT), str(path)], check=True)
    subprocess.run(["git", "-C", str(path), "checkout", "-q", commit], check=True)
    return path


def last_json(text: str) -> dict:
    for line in reversed(text.strip().splitlines()):
        if line.startswith("{"):
            return json.loads(line)
    raise ValueError("the bench printed no JSON line")


def run_bench(tree: Path, bench: str, args: list[str]) -> dict:
    proc = subprocess.run([sys.executable, f"bench/{bench}", *args], cwd=tree, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(tree)})
    if proc.returncode != 0:
        raise SystemExit(f"{bench} in {tree.name} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    return last_json(proc.stdout)


def figures(line: dict, prefix: str = "") -> dict[str, float]:
    """Every numeric leaf whose dotted path names a rate or a cost (a leaf under
    ``cpu_ms_per_step: {"1": ...}`` too)."""
    out: dict[str, float] = {}
    for key, value in line.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(figures(value, path + "."))
        elif isinstance(value, (int, float)) and not isinstance(value, bool) and any(f in path for f in FIGURES):
            out[path] = float(value)
    return out


def summary(before: list[dict], after: list[dict]) -> dict[str, dict[str, float]]:
    """Per figure: each side's median, their ratio, and the median of the rounds' own ratios
    (``before[i]`` and ``after[i]`` are round ``i``'s two runs)."""
    out = {}
    fb, fa = [figures(x) for x in before], [figures(x) for x in after]
    for name in sorted(set.intersection(*(set(f) for f in fb + fa))):
        b, a = statistics.median(f[name] for f in fb), statistics.median(f[name] for f in fa)
        rounds = [x[name] / y[name] for x, y in zip(fa, fb) if y[name]]
        out[name] = {"before": b, "after": a, "after_over_before": round(a / b, 4) if b else float("nan"),
                     "paired_after_over_before": round(statistics.median(rounds), 4) if rounds else float("nan")}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("before")
    parser.add_argument("after")
    parser.add_argument("--bench", required=True, help="a script in bench/, e.g. rl_env_speed.py")
    parser.add_argument("--runs", type=int, default=3, help="rounds, each running both sides (default 3)")
    parser.add_argument("--out", type=Path, help="folder for the raw lines (default: none kept)")
    parser.add_argument("--from", dest="kept", type=Path, help="run nothing: summarise the raw lines in this folder")
    argv = sys.argv[1:]
    split = argv.index("--") if "--" in argv else len(argv)
    opts, args = parser.parse_args(argv[:split]), argv[split + 1:]  # after --: the bench's own arguments
    if opts.runs < 1:
        parser.error("--runs must be >= 1")
    lines = kept_lines(opts.kept, opts.bench) if opts.kept else run_rounds(opts, args)
    refs = [x.get("machine_ref_rt") for side in lines.values() for x in side if x.get("machine_ref_rt")]
    print(json.dumps({"bench": opts.bench, "before": opts.before, "after": opts.after, "runs": len(lines["before"]),
                      "figures": summary(lines["before"], lines["after"]),
                      "machine_ref_rt": statistics.median(refs) if refs else None}))


def kept_lines(folder: Path, bench: str) -> dict[str, list[dict]]:
    """The raw lines an earlier run kept in ``folder``, each side in round order."""
    stem = Path(bench).stem
    lines: dict[str, list[dict]] = {}
    for side in ("before", "after"):
        files = sorted(folder.glob(f"{side}-{stem}-*.json"), key=lambda f: int(f.stem.rsplit("-", 1)[1]))
        lines[side] = [last_json(f.read_text()) for f in files]
    if not lines["before"] or len(lines["before"]) != len(lines["after"]):
        raise SystemExit(f"{folder}: {len(lines['before'])} before and {len(lines['after'])} after lines of {stem}")
    return lines


def run_rounds(opts: argparse.Namespace, args: list[str]) -> dict[str, list[dict]]:
    """``opts.runs`` rounds of both sides, the side that goes first alternating."""
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"before": clone(opts.before, Path(tmp)), "after": clone(opts.after, Path(tmp))}
        lines: dict[str, list[dict]] = {"before": [], "after": []}
        for i in range(opts.runs):
            order = ("before", "after") if i % 2 == 0 else ("after", "before")
            for side in order:
                print(f"round {i + 1}/{opts.runs}: {side}", file=sys.stderr, flush=True)
                line = run_bench(trees[side], opts.bench, args)
                lines[side].append(line)
                if opts.out is not None:
                    opts.out.mkdir(parents=True, exist_ok=True)
                    stem = Path(opts.bench).stem
                    (opts.out / f"{side}-{stem}-{i + 1}.json").write_text(json.dumps(line) + "\n")
    return lines


if __name__ == "__main__":
    main()
