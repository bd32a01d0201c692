"""The precision-landing comparison's first 10 starts, rerun at each commit, against each other and
against the committed episodes (results/precland/compare/episodes/), wall time aside.

    python results/episode-core/compare.py
"""

from __future__ import annotations

import json
from pathlib import Path

HERE = Path(__file__).resolve().parent
COMMITTED = HERE.parents[0] / "precland" / "compare" / "episodes"
RUNS = {"precland-px4": ("precland-px4-level-0.2.jsonl", ("at-2ac8ca0", "at-970ca43", "at-563051c", "at-ef1d8b2", "at-dab0327", "at-b52d975", "at-af67ec8")),
        "expert": ("expert-level-0.2.jsonl", ("at-970ca43", "at-563051c", "at-ef1d8b2", "at-dab0327", "at-b52d975", "at-af67ec8"))}


def records(path: Path, n: int | None = None) -> list[dict]:
    lines = [json.loads(line) for line in path.read_text().splitlines() if line.strip()][:n]
    return [{k: v for k, v in r.items() if k != "wall_time_s"} for r in lines]


def main() -> None:
    for arm, (committed_name, commits) in RUNS.items():
        runs = {c: records(HERE / c / f"{arm}-episodes.jsonl") for c in commits}
        committed = records(COMMITTED / committed_name, 10)
        for c, recs in runs.items():
            same = [a == b for a, b in zip(recs, committed, strict=True)]
            first = runs[commits[0]]
            print(json.dumps({"arm": arm, "commit": c, "episodes": len(recs),
                              f"same_as_{commits[0]}": sum(a == b for a, b in zip(recs, first, strict=True)),
                              "same_as_committed": sum(same),
                              "differ_from_committed": [r["seed"] for r, s in zip(recs, same, strict=True) if not s]}))


if __name__ == "__main__":
    main()
