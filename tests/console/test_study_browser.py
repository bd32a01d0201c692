"""``col study`` end to end in Debian's chromium with an emulated gamepad: one participant
(S01: Demo, Int, CoL) with a practice episode and 2 interactions a block, each block a trial
whose final policy flies the held-out starts and writes its results line, the questionnaire
answered or skipped after each, the study folder as the grid's report reads it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from companion.experiment.report import write_report
from companion.experiment.results import ResultsFile
from tests.conftest import ONE_AFTER_ANOTHER
from tests.console import REPO, start_col, stop
from tests.console.test_console_browser import (
    CHROMIUM,
    CHROMIUM_ARGS,
    FAKE_PAD,
    _browser_or_skip,
    _wait,
    shot,
)

pytestmark = [pytest.mark.realtime, pytest.mark.e2e, pytest.mark.xdist_group(ONE_AFTER_ANOTHER), pytest.mark.timeout(1500)]


def _block(page, condition: str, episodes: int) -> None:  # type: ignore[no-untyped-def]
    """Start the block the study names; end each episode after a few steps (the pad holds a stick)."""
    _wait(page, f"window.colConsole.study && window.colConsole.study.next && window.colConsole.study.next.condition === '{condition}'"
                f" && window.colConsole.study.next.episodes === {episodes} && !document.getElementById('start').disabled", 60)
    assert page.is_disabled("#condition") and page.input_value("#condition") == condition
    page.click("#start")
    for episode in range(episodes):
        if episode:
            _wait(page, "window.colConsole.status.run.state === 'ready'", 120)
            page.click("#go")
        _wait(page, f"window.colConsole.lastStep && window.colConsole.lastStep.episode === {episode}"
                    " && window.colConsole.lastStep.step >= 12 && window.colConsole.status.run.state === 'running'", 240)
        page.click("#next")
    _wait(page, "window.colConsole.status.run.state === 'finished'", 180)


def test_one_participant_flies_the_study_and_it_is_written_as_the_grid_writes(tmp_path: Path) -> None:
    _browser_or_skip()
    from playwright.sync_api import sync_playwright

    config = tmp_path / "study.toml"  # the paper's task and learner, 2 held-out starts a trial
    config.write_text((REPO / "configs" / "paper.toml").read_text().replace("eval_runs = 100", "eval_runs = 2"))
    out, log = tmp_path / "S01", tmp_path / "study.log"
    proc, url = start_col(log, "study", "--participant", "S01", "--out", str(out), "--config", str(config),
                          "--interactions", "2", "--practice", "1", "--port", "0", "-v")
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.add_init_script(FAKE_PAD)
            page.on("dialog", lambda dialog: dialog.accept())
            page.goto(url)
            _wait(page, "window.colConsole.hello !== null && window.colConsole.role !== null", 20)
            page.click("#take-role")
            _wait(page, "window.colConsole.role.role === 'pilot'", 10)
            assert "demo, int, col" in page.inner_text("#study-info")
            page.evaluate("window.__pad.axes[3] = -0.4")  # pitch forward: the person flies in demonstrations

            _block(page, "demo", 1)  # the practice
            for condition, answer in (("demo", True), ("int", False), ("col", True)):
                _block(page, condition, 2)
                _wait(page, "window.colConsole.study.questionnaire_for !== null", 300)  # evaluated first
                assert page.is_visible("#tlx")
                if answer:
                    page.fill("#tlx input[data-scale='effort']", "80")
                    page.click("#tlx-submit")
                else:
                    page.click("#tlx-skip")
                _wait(page, "window.colConsole.study.questionnaire_for === null", 20)
            _wait(page, "window.colConsole.study.next === null", 10)
            assert "complete" in page.inner_text("#study-info")
            shot(page, tmp_path, "study_complete.png")
            browser.close()
    finally:
        stop(proc)

    results = ResultsFile(out / "results.jsonl").load()
    assert [r.trial.key for r in results] == ["S01-demo-02-s0", "S01-int-02-s0", "S01-col-02-s0"], log.read_text()[-3000:]
    assert all(r.status == "ok" and r.eval_runs == 2 for r in results)
    demo, intervene, col = results
    assert demo.human_samples > 0 and col.human_samples > 0  # the person's demonstrations were recorded
    for r in results:
        trial = out / "trials" / r.trial.key
        assert (trial / "train" / "checkpoints" / "episode_001.npz").exists() and (trial / "train" / "human.csv").exists()
        assert len((trial / "eval_episodes.jsonl").read_text().splitlines()) == 2
    answers = [json.loads(x) for x in (out / "questionnaire.jsonl").read_text().splitlines()]
    assert [(a["block"], a["skipped"]) for a in answers] == [("S01-demo-02-s0", False), ("S01-int-02-s0", True),
                                                             ("S01-col-02-s0", False)]
    assert answers[0]["answers"]["effort"] == 80 and answers[0]["answers"]["mental"] == 50
    report = write_report(results, tmp_path / "report").read_text()  # the grid's report reads the person's trials
    per_participant = [line for line in report.splitlines() if line.startswith("| S01 |")]
    assert len(per_participant) == 1 and "| 2 | Demo | 1 |" in report and "| 2 | CoL | 1 |" in report, report
