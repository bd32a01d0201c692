"""The batched evaluation flies the session's evaluation episodes.

``evaluate_checkpoint`` is run both ways (``eval_batched`` true and false, both in-process) on
the same held-out starts at ``configs/paper.toml``'s disturbance (level 0.2) with a small
deterministic policy (the paper's 15-130-72-40-4 network, weights set to steer towards the pad
it sees plus dense noise): every record must be the same, field for field and in the same JSON
text but the session's wall time, and every touchdown point within 1 mm. The policies are built
here rather than trained, so the test takes seconds. (Touchdown points and speeds are compared
within 1 mm and 1e-9 m/s, not bit for bit: a lane's clock is not the session's, and the driving
pad's position, its velocity times the time since the episode's start, can round apart in the
last bit; the vehicle on the moving roof carries that into its state.) The policies: one lands (on the pad and beside it), one
also gives a non-finite yaw whenever the pad is out of view (repaired as the session repairs
it), and a small geofence with a short episode gives fence exits (at the first step too) and
timeouts.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from companion.app import RunResult
from companion.commands import CommandMapper
from companion.config import LearnerConfig
from companion.errors import CheckpointError, LinkError, SessionOnly
from companion.experiment import batched_eval
from companion.experiment.batched_eval import (
    SESSION_ONLY_FIELDS,
    BatchedEvaluation,
    evaluate_batched,
    why_not_batched,
)
from companion.experiment.grid import (
    ExperimentConfig,
    ExperimentSetup,
    TrainingRun,
    load_experiment,
)
from companion.experiment.runner import evaluate_checkpoint, trial_config
from companion.learning.checkpoint import save_checkpoint
from companion.learning.ensemble import EnsembleSnapshot
from companion.learning.snapshot import Normalisation, PolicySnapshot
from companion.msg.episode import EpisodeRecord
from companion.rl.direct_sitl import DirectSitl
from companion.rl.landing_lane import LandingLane
from companion.simulator import SimulatorClient

PAPER = Path(__file__).resolve().parents[2] / "configs" / "paper.toml"  # [sitl.disturbance] level = 0.2
EVAL_RUNS = 8
TOUCHDOWN_TOLERANCE_M = 1e-3
RUN = TrainingRun("P1", "demo", 0, 2, (2,))
PAD_U, PAD_V, PAD_RADIUS = 12, 13, 14  # observation entries (companion/msg/observation.py)
ROLL, PITCH, YAW, THROTTLE = range(4)  # policy outputs (JoystickCommand order)
GAIN, THROTTLE_BIAS = 0.2, -1.5  # steers weakly, descends fast: lands on the pad from half the starts


# ----- policies ------------------------------------------------------------------------------
def _lander(nan_yaw: bool, gain: float = GAIN, throttle: float = THROTTLE_BIAS, seed: int = 0) -> PolicySnapshot:
    """15-130-72-40-4: the first layer splits every input into its positive and negative parts,
    the next two pass them on, the last steers towards the pad (roll gain x u, pitch -gain x v)
    and descends (throttle tanh(bias)); N(0, 1e-3) on every weight makes every product dense.
    ``nan_yaw``: the yaw row also adds +3e38 and -3e38 times two copies of 2 x "pad not
    visible", which overflow to inf - inf = NaN while the pad is out of view."""
    rng = np.random.default_rng(seed)
    w1, w2, w3, w4 = (rng.normal(0.0, 1e-3, shape) for shape in ((130, 15), (72, 130), (40, 72), (4, 40)))
    for j in range(15):
        w1[j, j], w1[15 + j, j] = 1.0, -1.0
    for w in (w2, w3):
        for j in range(31):
            w[j, j] = 1.0
    w4[ROLL, PAD_U], w4[ROLL, 15 + PAD_U] = gain, -gain
    w4[PITCH, PAD_V], w4[PITCH, 15 + PAD_V] = -gain, gain
    b4 = np.array([0.0, 0.0, 0.0, throttle])
    if nan_yaw:
        w1[15 + PAD_RADIUS, PAD_RADIUS] = w1[30, PAD_RADIUS] = -2.0  # 2 when the radius reads -1
        w4[YAW, 15 + PAD_RADIUS], w4[YAW, 30] = 3e38, -3e38
    biases = (np.zeros(130), np.zeros(72), np.zeros(40), b4)
    return PolicySnapshot((w1, w2, w3, w4), biases, Normalisation.identity(), version=7)


def _checkpoint(folder: Path, snapshot: PolicySnapshot) -> Path:
    return save_checkpoint(folder / "policy.npz", snapshot, LearnerConfig(), dataset_size=0, episode=1,
                           condition="demo")


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning", "ignore:invalid value encountered:RuntimeWarning")
def test_the_policies_do_what_the_tests_need() -> None:
    hidden = np.zeros(15, np.float32)
    hidden[PAD_RADIUS] = -1.0  # pad not visible
    assert np.isnan(_lander(True).act(hidden)[YAW]) and np.isfinite(_lander(True).act(hidden)[[0, 1, 3]]).all()
    seen = hidden.copy()
    seen[[PAD_U, PAD_V, PAD_RADIUS]] = (0.3, -0.2, 0.4)
    action = _lander(True).act(seen)
    assert np.isfinite(action).all() and action[ROLL] > 0.05 and action[PITCH] > 0.03 and action[THROTTLE] < -0.9


# ----- both ways -----------------------------------------------------------------------------
def _setup(folder: Path, extra: str = "") -> ExperimentSetup:
    path = folder / "experiment.toml"
    path.write_text(PAPER.read_text() + "\n" + extra)
    return load_experiment(path)


@dataclasses.dataclass
class _Evaluated:
    lines: list[str]  # eval_episodes.jsonl, as written
    touchdowns: dict[int, dict[str, Any]]  # by seed: the ground truth's touchdown
    result: object
    repairs: int  # non-finite actions repaired


@pytest.fixture
def truths(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, list[Any]]]:
    """The ground truths both evaluations read (the session's in episode order, the batched
    one's with the seed its lane flies) and the non-finite actions the mappers repaired."""
    seen: dict[str, list[Any]] = {"session": [], "batched": [], "repairs": []}
    lane_seed: dict[int, int] = {}
    session_truth, lane_truth, begin = SimulatorClient.truth, DirectSitl.truth, LandingLane.begin
    command_from_values = CommandMapper.command_from_values

    def on_values(self: CommandMapper, values: Any) -> Any:
        if not np.isfinite(values).all():
            seen["repairs"].append(np.asarray(values).copy())
        return command_from_values(self, values)

    def on_session(self: SimulatorClient) -> dict[str, Any]:
        reply = session_truth(self)
        seen["session"].append(reply.get("touchdown"))
        return reply

    def on_lane(self: DirectSitl) -> dict[str, Any]:
        reply = lane_truth(self)
        seen["batched"].append((lane_seed.get(id(self)), reply.get("touchdown")))
        return reply

    def on_begin(self: LandingLane, seed: int | None, attempts: int = 3) -> Any:
        if seed is not None:
            lane_seed[id(self.sitl)] = seed
        return begin(self, seed, attempts)

    monkeypatch.setattr(SimulatorClient, "truth", on_session)
    monkeypatch.setattr(DirectSitl, "truth", on_lane)
    monkeypatch.setattr(LandingLane, "begin", on_begin)
    monkeypatch.setattr(CommandMapper, "command_from_values", on_values)
    yield seen


def _evaluate(setup: ExperimentSetup, checkpoint: Path, folder: Path, batched: bool,
              truths: dict[str, list[Any]], members: int = 1) -> _Evaluated:
    exp = setup.exp.model_copy(update={"eval_runs": EVAL_RUNS, "eval_batched": batched})
    cfg = trial_config(setup, RUN)
    cfg = cfg.model_copy(update={"learner": cfg.learner.model_copy(update={"ensemble_members": members})})
    folder.mkdir()
    key = "batched" if batched else "session"
    truths[key].clear()
    truths["repairs"].clear()
    result = evaluate_checkpoint(dataclasses.replace(setup, exp=exp), cfg, checkpoint, folder)
    lines = (folder / "eval_episodes.jsonl").read_text().splitlines()
    seeds = [json.loads(line)["seed"] for line in lines]
    if batched:
        touchdowns = {seed: td for seed, td in truths[key] if td is not None}
    else:
        touchdowns = {seed: td for seed, td in zip(seeds, truths[key], strict=True) if td is not None}
    return _Evaluated(lines, touchdowns, result, len(truths["repairs"]))


def _without_wall_time(line: str) -> str:
    record = json.loads(line)
    del record["wall_time_s"]
    return json.dumps(record)


def _assert_same_episodes(session: _Evaluated, batched: _Evaluated) -> list[dict[str, Any]]:
    """Same records (as JSON text, wall time aside) and touchdowns; the records."""
    assert isinstance(session.result, RunResult) and isinstance(batched.result, BatchedEvaluation)
    assert batched.lines == [_without_wall_time(line) for line in session.lines]
    records = [json.loads(line) for line in batched.lines]
    assert [r["seed"] for r in records] == list(range(100_000, 100_000 + EVAL_RUNS))
    assert [r["episode"] for r in records] == list(range(EVAL_RUNS))
    assert batched.result.successes == session.result.successes == sum(1 for r in records if r["success"])
    assert batched.repairs == session.repairs
    touched = [r["seed"] for r in records if r["outcome"] == "touchdown"]
    assert sorted(session.touchdowns) == sorted(batched.touchdowns) == sorted(touched)
    for seed in touched:
        a, b = session.touchdowns[seed], batched.touchdowns[seed]
        assert math.dist(a["ned"], b["ned"]) <= TOUCHDOWN_TOLERANCE_M
        assert a["success"] == b["success"] and a["speed_m_s"] == pytest.approx(b["speed_m_s"], abs=1e-9)
    return records


def _both(tmp_path: Path, snapshot: PolicySnapshot, truths: dict[str, list[Any]],
          extra: str = "") -> tuple[list[dict[str, Any]], int]:
    """The records (the same both ways) and the number of repaired actions (the same too)."""
    setup = _setup(tmp_path, extra)
    checkpoint = _checkpoint(tmp_path, snapshot)
    members = snapshot.members if isinstance(snapshot, EnsembleSnapshot) else 1
    session = _evaluate(setup, checkpoint, tmp_path / "session", False, truths, members)
    batched = _evaluate(setup, checkpoint, tmp_path / "batched", True, truths, members)
    return _assert_same_episodes(session, batched), batched.repairs


def test_same_episodes_as_the_session_at_the_experiments_disturbance(
        tmp_path: Path, truths: dict[str, list[Any]], monkeypatch: pytest.MonkeyPatch) -> None:
    """Three lanes: the starts fly interleaved, each lane's clock unlike the session's."""
    monkeypatch.setattr(batched_eval, "DEFAULT_LANES", 3)
    records, repairs = _both(tmp_path, _lander(nan_yaw=False), truths)
    assert {(r["outcome"], r["success"]) for r in records} == {("touchdown", True), ("touchdown", False)}
    assert {r["policy_version"] for r in records} == {7} and repairs == 0


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning", "ignore:invalid value encountered:RuntimeWarning")
def test_a_policy_that_gives_nan_is_repaired_as_the_session_repairs_it(
        tmp_path: Path, truths: dict[str, list[Any]], caplog: pytest.LogCaptureFixture,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Yaw is NaN while the pad is out of view: repaired to 0 (and logged) the same number of
    times; two lanes."""
    monkeypatch.setattr(batched_eval, "DEFAULT_LANES", 2)
    with caplog.at_level(logging.WARNING, logger="companion.commands"):
        records, repairs = _both(tmp_path, _lander(nan_yaw=True), truths)
    assert repairs > 0 and any("repaired a joystick command" in m for m in caplog.messages)
    assert {r["success"] for r in records} == {True, False}


def test_an_ensemble_flies_its_mean_action_as_in_the_session(tmp_path: Path, truths: dict[str, list[Any]]) -> None:
    """Three members (configs/ask.toml's grids train five): the checkpoint through a Learner of
    three, the members' mean action."""
    members = [_lander(nan_yaw=False, gain=g, seed=s) for s, g in enumerate((0.1, 0.2, 0.3))]
    records, _ = _both(tmp_path, EnsembleSnapshot.of_members(members, version=9), truths)
    assert {r["policy_version"] for r in records} == {9} and {r["success"] for r in records} == {True, False}


def test_same_fence_exits_and_timeouts(tmp_path: Path, truths: dict[str, list[Any]]) -> None:
    """A 2.5 m geofence around the pad (starts lie within 3 m of it) and 40-step episodes; the
    default lane count."""
    extra = "[companion.session]\nmax_steps = 40\n\n[companion.safety]\nfence_radius_m = 2.5\n"
    records, _ = _both(tmp_path, _lander(nan_yaw=False), truths, extra)
    outcomes = {(r["outcome"], r["steps"], r["policy_version"]) for r in records}
    assert ("fence", 1, None) in outcomes  # outside at the first frame: the session's fence test
    assert ("timeout", 40, 7) in outcomes


# ----- records and options -------------------------------------------------------------------
def test_records_have_the_sessions_fields_in_its_order_but_the_wall_time(tmp_path: Path) -> None:
    setup = _setup(tmp_path, "[companion.session]\nmax_steps = 3\n")
    evaluation = evaluate_batched(trial_config(setup, RUN), _checkpoint(tmp_path, _lander(False)), 5, 2,
                                  setup.config_path, lanes=2)
    names = [f.name for f in dataclasses.fields(EpisodeRecord)]
    assert SESSION_ONLY_FIELDS == ("wall_time_s",)
    for record in evaluation.records:
        assert list(record.to_json_dict()) == [n for n in names if n not in SESSION_ONLY_FIELDS]
    assert [(r.episode, r.seed, r.outcome, r.steps) for r in evaluation.records] == [(0, 5, "timeout", 3),
                                                                                    (1, 6, "timeout", 3)]


def test_the_option_is_on_by_default_and_not_part_of_the_fingerprint() -> None:
    setup = load_experiment(PAPER)
    assert ExperimentConfig().eval_batched is True and setup.exp.eval_batched is True
    off = dataclasses.replace(setup, exp=setup.exp.model_copy(update={"eval_batched": False}))
    assert off.fingerprint() == setup.fingerprint()


def test_a_missing_checkpoint_is_a_clear_error(tmp_path: Path) -> None:
    setup = _setup(tmp_path)
    with pytest.raises(CheckpointError, match="does not exist"):
        evaluate_batched(trial_config(setup, RUN), tmp_path / "nope.npz", 100_000, 2, setup.config_path)
    with pytest.raises(CheckpointError, match="does not exist"):
        evaluate_checkpoint(setup, trial_config(setup, RUN), tmp_path / "nope.npz", tmp_path)


def test_settings_only_the_session_flies_are_named(tmp_path: Path) -> None:
    cfg = trial_config(load_experiment(PAPER), RUN)
    assert why_not_batched(cfg, PAPER) is None
    assist = cfg.model_copy(update={"landing": cfg.landing.model_copy(update={"touchdown_assist": True})})
    assert "touchdown assist" in (why_not_batched(assist, PAPER) or "")
    camera = cfg.model_copy(update={"perception": cfg.perception.model_copy(update={"camera": "render"})})
    assert "camera" in (why_not_batched(camera, PAPER) or "")
    with pytest.raises(SessionOnly, match="touchdown assist"):
        evaluate_batched(assist, _checkpoint(tmp_path, _lander(False)), 100_000, 1, PAPER)


def test_an_episode_that_cannot_start_is_evaluated_by_the_session(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The session records an "error" episode and goes on; the batched path gives way to it."""
    setup = _setup(tmp_path, "[companion.session]\nmax_steps = 3\n")
    begin = LandingLane.begin

    def failing(self: LandingLane, seed: int | None, attempts: int = 3) -> Any:
        if seed == 100_001:
            raise LinkError("the vehicle did not report being in the air after the reset")
        return begin(self, seed, attempts)

    monkeypatch.setattr(LandingLane, "begin", failing)
    with pytest.raises(SessionOnly, match="episode 1 .seed 100001. could not start"):
        evaluate_batched(trial_config(setup, RUN), _checkpoint(tmp_path, _lander(False)), 100_000, 3,
                         setup.config_path, lanes=2)
    exp = setup.exp.model_copy(update={"eval_runs": 3})
    result = evaluate_checkpoint(dataclasses.replace(setup, exp=exp), trial_config(setup, RUN),
                                 tmp_path / "policy.npz", tmp_path)
    assert isinstance(result, RunResult) and [r.outcome for r in result.records] == ["timeout"] * 3
    assert len((tmp_path / "eval_episodes.jsonl").read_text().splitlines()) == 3
