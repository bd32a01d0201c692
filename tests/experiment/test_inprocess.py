"""Evaluation in-process flies the same episodes as evaluation over lockstep MAVLink.

The issue's rule: if evaluation runs over any other path than lockstep MAVLink, a test must show
the same outcome and touchdown position (within 1 mm) as over MAVLink for the same seeds. Here a
policy trained for two episodes (so that its starts end in hits, misses and timeouts alike) is
evaluated by ``evaluate_checkpoint`` both ways on the same held-out starts, undisturbed and with
``[sitl.disturbance] level = 0.2`` (wind, turbulence, heading, camera noise, misalignment and
latency, attitude noise): every episode record must be the same (wall time aside), and every
ground-truth touchdown point within 1 mm (in practice they are bit-identical: the same bytes
and pixels reach the same code).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import pytest

import companion.app as app
from companion.app import RunOptions
from companion.config import CompanionConfig
from companion.errors import ConfigError
from companion.experiment.grid import (
    ExperimentConfig,
    ExperimentSetup,
    TrainingRun,
    load_experiment,
)
from companion.experiment.runner import evaluate_checkpoint, train_run, trial_config
from companion.inprocess import InProcessLink, InProcessSitl, inprocess_vehicle, sitl_config_for
from companion.simulator import SimulatorClient

REPO = Path(__file__).resolve().parents[2]
QUICK = REPO / "configs" / "experiment_quick.toml"
EVAL_RUNS = 6
TOUCHDOWN_TOLERANCE_M = 1e-3
SAME_FIELDS = ("seed", "outcome", "steps", "success", "touchdown_distance_m", "touchdown_speed_m_s", "sim_time_s")


def _config(folder: Path, disturbance_level: float) -> Path:
    """The quick experiment file, with short timeouts (a miss ends at 250 steps) and a disturbance."""
    path = folder / f"level_{disturbance_level}.toml"
    text = QUICK.read_text() + f"\n[companion.session]\nmax_steps = 250\n\n[sitl.disturbance]\nlevel = {disturbance_level}\n"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(folder, checkpoint): P1's policy after two demonstrations, trained over MAVLink."""
    folder = tmp_path_factory.mktemp("inprocess")
    setup = load_experiment(_config(folder, 0.0))
    run = TrainingRun("P1", "demo", 0, 2, (2,))
    train_run(setup, trial_config(setup, run), run, folder / "train")
    return folder, folder / "train" / "checkpoints" / "episode_001.npz"


def _evaluate(setup: ExperimentSetup, checkpoint: Path, folder: Path, inprocess: bool,
              monkeypatch: pytest.MonkeyPatch) -> tuple[list[dict[str, Any]], list[dict[str, Any] | None]]:
    """The evaluation records (without wall times) and the ground-truth touchdowns, in order."""
    touchdowns: list[dict[str, Any] | None] = []
    truth = SimulatorClient.truth  # the in-process simulator inherits it

    def recording_truth(self: SimulatorClient) -> dict[str, Any]:
        reply = truth(self)
        touchdowns.append(reply.get("touchdown"))
        return reply

    def no_sitl_process(*args: object, **kwargs: object) -> object:
        raise AssertionError("in-process evaluation started a SITL process")

    monkeypatch.setattr(SimulatorClient, "truth", recording_truth)
    if inprocess:
        monkeypatch.setattr(app, "start_sitl", no_sitl_process)
    exp = setup.exp.model_copy(update={"eval_runs": EVAL_RUNS, "eval_inprocess": inprocess,
                                       "eval_batched": False})  # the session's path both ways
    run = TrainingRun("P1", "demo", 0, 2, (2,))
    folder.mkdir()
    evaluate_checkpoint(dataclasses.replace(setup, exp=exp), trial_config(setup, run), checkpoint, folder)
    monkeypatch.undo()
    records = [json.loads(line) for line in (folder / "eval_episodes.jsonl").read_text().splitlines()]
    for record in records:
        del record["wall_time_s"]
    return records, touchdowns


@pytest.mark.e2e
@pytest.mark.parametrize("level", [0.0, 0.2])
def test_inprocess_evaluation_flies_the_same_episodes_as_over_mavlink(
        trained: tuple[Path, Path], level: float, monkeypatch: pytest.MonkeyPatch) -> None:
    folder, checkpoint = trained
    setup = load_experiment(_config(folder, level))
    over_mavlink, mavlink_touchdowns = _evaluate(setup, checkpoint, folder / f"mavlink_{level}", False, monkeypatch)
    in_process, inprocess_touchdowns = _evaluate(setup, checkpoint, folder / f"inprocess_{level}", True, monkeypatch)

    assert [r["seed"] for r in over_mavlink] == list(range(100_000, 100_000 + EVAL_RUNS))
    for a, b in zip(over_mavlink, in_process, strict=True):
        assert {k: a[k] for k in SAME_FIELDS} == {k: b[k] for k in SAME_FIELDS}
        assert a == b  # and every other field of the record
    assert len(mavlink_touchdowns) == len(inprocess_touchdowns) == EVAL_RUNS
    touched = 0
    for a, b in zip(mavlink_touchdowns, inprocess_touchdowns, strict=True):
        assert (a is None) == (b is None)
        if a is not None and b is not None:
            touched += 1
            assert math.dist(a["ned"], b["ned"]) <= TOUCHDOWN_TOLERANCE_M
            assert (a["speed_m_s"], a["success"]) == (b["speed_m_s"], b["success"])
    assert touched >= 1  # the positions were compared, not only the absence of a touchdown


def test_the_inprocess_vehicle_connects_starts_an_episode_and_leaves_opencv_as_it_was(tmp_path: Path) -> None:
    import cv2

    threads = cv2.getNumThreads()
    with inprocess_vehicle(CompanionConfig(), RunOptions(seed=7), True, tmp_path) as vehicle:
        assert cv2.getNumThreads() == 1  # as the SITL process renders
        assert vehicle.link.state() is not None and vehicle.simulator is not None and vehicle.camera is not None
        start = vehicle.simulator.reset(7)
        snapshot = vehicle.link.wait_frame(start["time_boot_ms"], timeout_s=1.0)
        assert snapshot is not None and snapshot.in_air
        frame = vehicle.camera.frame_at(int(snapshot.frame_time_boot_ms or 0), timeout_s=0.0)
        assert frame is not None and frame.image.shape == (240, 320, 3)
    assert cv2.getNumThreads() == threads


def test_an_inprocess_vehicle_silent_while_the_companion_thinks_is_not_a_lost_link() -> None:
    """It speaks only when advanced: minutes of the wall clock without a step are not a link loss
    (a loaded CI machine had ended an episode as link_lost before its first step)."""
    now = [0.0]
    cfg = CompanionConfig()
    sitl = InProcessSitl(sitl_config_for(cfg, RunOptions(seed=7)))
    link = InProcessLink(cfg.link, sitl, clock=lambda: now[0])
    try:
        link.connect(timeout_s=30.0)
        assert link.link_alive()
        now[0] += 10 * cfg.link.link_lost_s  # nothing sent, nothing heard
        assert link.link_alive()
        assert link.send_statustext("COL: still here") is not False  # raised LinkLost before
        assert link.stats().reconnections == 0
    finally:
        link.close()
        sitl.close()
    assert not link.link_alive()  # closed: lost


def test_an_inprocess_run_refuses_another_vehicle_or_camera(tmp_path: Path) -> None:
    """It flies its own lockstep SITL and that SITL's camera, nothing else."""
    cfg = CompanionConfig()
    with pytest.raises(ConfigError, match="--connect"):
        with inprocess_vehicle(cfg, RunOptions(connection="udpin:127.0.0.1:14540"), True, tmp_path):
            pass
    with pytest.raises(ConfigError, match="lockstep"):
        with inprocess_vehicle(cfg, RunOptions(), False, tmp_path):
            pass
    other_camera = cfg.model_copy(update={"perception": cfg.perception.model_copy(update={"camera": "0"})})
    with pytest.raises(ConfigError, match="eval_inprocess"):
        with inprocess_vehicle(other_camera, RunOptions(), True, tmp_path):
            pass


def test_evaluation_runs_in_process_unless_the_file_says_otherwise(tmp_path: Path) -> None:
    assert ExperimentConfig().eval_inprocess is True
    assert all(load_experiment(REPO / "configs" / name).exp.eval_inprocess
               for name in ("experiment.toml", "experiment_quick.toml", "paper.toml"))
    over_mavlink = tmp_path / "mavlink.toml"
    over_mavlink.write_text(QUICK.read_text().replace("eval_inprocess = true", "eval_inprocess = false"))
    assert load_experiment(over_mavlink).exp.eval_inprocess is False
