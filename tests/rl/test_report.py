"""The PPO grid report: curves per 50 episodes with a band over seeds, final evaluations, CoL."""

from __future__ import annotations

import json
from pathlib import Path

from companion.experiment.grid import Trial
from companion.experiment.results import TrialResult
from companion.rl.report import col_result, curve_band, plot, read_runs, summary


def write_run(folder: Path, successes: list[bool], final: dict | None = None) -> None:
    folder.mkdir(parents=True)
    lines = [json.dumps({"episode": i, "seed": i, "steps": 200, "outcome": "touchdown", "success": s,
                         "touchdown_distance_m": 0.2 if s else 3.0, "wall_s": float(i)}) for i, s in enumerate(successes)]
    (folder / "train_episodes.jsonl").write_text("\n".join(lines) + "\n")
    if final is not None:
        (folder / "results.json").write_text(json.dumps(final))


def test_curve_band_is_mean_min_max_over_the_seeds_that_finished_each_block(tmp_path: Path) -> None:
    write_run(tmp_path / "a2-s0", [False] * 50 + [True] * 50)
    write_run(tmp_path / "a2-s1", [False] * 50 + [True] * 25 + [False] * 25 + [True] * 10)  # 3rd block unfinished
    write_run(tmp_path / "notarun", [True])
    runs = read_runs(tmp_path)
    assert set(runs) == {2} and set(runs[2]) == {0, 1}
    band = curve_band(runs[2])
    assert band == [{"first_episode": 0, "seeds": 2, "mean": 0.0, "min": 0.0, "max": 0.0},
                    {"first_episode": 50, "seeds": 2, "mean": 0.75, "min": 0.5, "max": 1.0}]


def test_summary_and_plot_with_final_evaluations_and_col(tmp_path: Path) -> None:
    final = {"eval": {"episodes": 100, "successes": 7, "success_rate": 0.07, "ci95": [0.03, 0.14], "touchdowns": 90,
                      "timeouts": 5, "fence": 5}, "train": {"successes": 3, "wall_s": 10.0}}
    write_run(tmp_path / "grid" / "a3-s0", [False] * 100, final)
    col = tmp_path / "results.jsonl"
    rows = [TrialResult(Trial("P1", c, n, seed), "f", "ok", eval_runs=100, eval_successes=k).to_json_line()
            for c, n, seed, k in [("col", 20, 0, 90), ("col", 20, 1, 80), ("demo", 20, 0, 10), ("col", 8, 0, 0),
                                  ("col", 20, 0, 90)]]  # a trial written twice counts once
    rows.append(TrialResult(Trial("P1", "col", 20, 2), "f", "error", error="boom").to_json_line())
    col.write_text("\n".join(rows) + "\n")
    assert col_result(col) == {"interactions": 20, "trials": 2, "success_rate_mean": 0.85, "success_rate_sd": 0.0707}
    result = summary(tmp_path / "grid", None, col)
    assert result["final_policies"]["a3-s0"]["successes"] == 7 and result["training_successes"] == {"a3": {"0": 0}}
    plot(result, tmp_path / "curves.png")
    assert (tmp_path / "curves.png").read_bytes()[:4] == b"\x89PNG"


def test_runs_table_row_counts_outcomes_blocks_and_the_held_out_evaluation(tmp_path: Path) -> None:
    from companion.rl.report import RUNS_HEADER, runs_table

    final = {"eval": {"episodes": 100, "successes": 7, "success_rate": 0.07, "ci95": [0.03, 0.14], "touchdowns": 90,
                      "timeouts": 5, "fence": 5, "touchdown_distance_m_median": 1.5}}
    write_run(tmp_path / "g" / "a2-s1", [False] * 60 + [True] * 90, final)
    (tmp_path / "g" / "a2-s1" / "settings.json").write_text(json.dumps({"action_dims": 2, "seed": 1, "log_std_init": -1.0}))
    write_run(tmp_path / "g" / "a4-s0", [False] * 3)
    (tmp_path / "g" / "a4-s0" / "settings.json").write_text(json.dumps(
        {"action_dims": 4, "seed": 0, "log_std_init": 0.0, "normalize_advantage": False}))
    table = runs_table(tmp_path, ["g/a2-s1", "g/a4-s0"]).splitlines()
    assert table[:2] == RUNS_HEADER.splitlines()
    assert table[2] == ("| g/a2-s1 | 2 | 1 | -1.0 | yes | 150 | 90 | touchdown 150 | 3.0, 0.2, 0.2 (per 50) | 40, 50 "
                        "| 7/100 (3-14 %); 90 touchdowns, 5 timeouts, 5 fence exits; median 1.5 m (policy after 150 episodes) |")
    assert table[3].startswith("| g/a4-s0 | 4 | 0 | 0.0 | no | 3 | 0 |") and table[3].endswith("| not flown (unfinished) |")
