"""Wiring of a run folder by ``run_episodes``: what a second run in the same folder does, and
what a refused start leaves behind."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from companion.app import (
    RunOptions,
    RunResult,
    check_lockstep,
    next_episode,
    open_run_camera,
    run_episodes,
)
from companion.config import CompanionConfig
from companion.errors import CameraError, CheckpointError, ConfigError
from companion.learning.dataset import load_csv
from companion.link.dialect import ARDUPILOT, PX4
from companion.msg.episode import EpisodeRecord
from companion.simulator import SitlProcess
from companion.vision.camera import open_camera


def test_a_missing_checkpoint_fails_before_making_the_run_folder(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    opts = RunOptions(pilot="none", condition="eval", episodes=1, checkpoint=tmp_path / "nope.npz", run_dir=run_dir)
    with pytest.raises(CheckpointError, match="does not exist"):
        run_episodes(CompanionConfig(), opts)
    assert not run_dir.exists()


def test_next_episode_follows_the_checkpoints(tmp_path: Path) -> None:
    assert next_episode(tmp_path) == 0
    (tmp_path / "checkpoints").mkdir()
    for name in ("episode_000.npz", "episode_004.npz", "episode_x.npz", ".episode_007.npz.1.tmp"):
        (tmp_path / "checkpoints" / name).write_bytes(b"")
    assert next_episode(tmp_path) == 5


@pytest.mark.e2e
def test_a_resumed_run_folder_numbers_episodes_on_and_keeps_earlier_checkpoints(tmp_path: Path) -> None:
    base = CompanionConfig()
    cfg = base.model_copy(update={"session": base.session.model_copy(update={"max_steps": 5})})  # short episodes
    for _ in range(2):
        run_episodes(cfg, RunOptions(pilot="expert", condition="demo", episodes=1, run_dir=tmp_path, learn=False))
    records = [json.loads(line) for line in (tmp_path / "episodes.jsonl").read_text().splitlines()]
    assert [(r["episode"], r["seed"]) for r in records] == [(0, 0), (1, 1)]  # new episode, new start
    assert sorted(p.name for p in (tmp_path / "checkpoints").glob("*.npz")) == ["episode_000.npz", "episode_001.npz"]
    assert sorted(set(load_csv(tmp_path / "human.csv").episode.tolist())) == [0, 1]


class _NoCameraLink:
    def request_message(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        return None  # no camera component answers


def _with_camera(spec: str) -> CompanionConfig:
    cfg = CompanionConfig()
    return cfg.model_copy(update={"perception": cfg.perception.model_copy(update={"camera": spec, "open_timeout_s": 0.2})})


def test_a_named_camera_that_does_not_open_is_an_error_even_with_our_sitl(tmp_path: Path) -> None:
    sitl = SitlProcess(proc=None, ports={"camera_uri": None})  # type: ignore[arg-type]
    with pytest.raises(CameraError, match="nope.mp4"):
        open_run_camera(_with_camera(str(tmp_path / "nope.mp4")), sitl, _NoCameraLink())  # type: ignore[arg-type]
    # "auto" with a SITL whose camera is off: fly on, the pad counted as not visible
    assert open_run_camera(_with_camera("auto"), sitl, _NoCameraLink()) is None  # type: ignore[arg-type]


def test_next_episode_also_follows_the_records_of_a_run_without_checkpoints(tmp_path: Path) -> None:
    from companion.app import next_episode

    (tmp_path / "episodes.jsonl").write_text('{"episode": 0}\n{"episode": 4}\n{"episo')
    assert next_episode(tmp_path) == 5


def test_an_unknown_pilot_fails_before_any_simulator_starts(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import companion.app as app
    from companion.errors import ConfigError

    started: list[int] = []
    monkeypatch.setattr(app, "start_sitl", lambda *a, **k: started.append(1))
    with pytest.raises(ConfigError, match="unknown pilot"):
        run_episodes(CompanionConfig(), RunOptions(pilot="robot", episodes=1, run_dir=tmp_path / "r"))
    assert not started


def test_a_resumed_run_folder_continues_from_its_newest_policy(tmp_path: Path) -> None:
    from companion.app import _resume_policy
    from companion.learning.checkpoint import save_checkpoint
    from companion.learning.policy import PolicyNet

    assert _resume_policy(tmp_path, 3) is None  # nothing to resume from
    (tmp_path / "checkpoints").mkdir()
    cfg = CompanionConfig().learner
    snap = PolicyNet(15, cfg.hidden, init_std=0.1).snapshot(version=42)
    save_checkpoint(tmp_path / "checkpoints" / "episode_001.npz", snap, cfg, dataset_size=10, episode=1, condition="demo")
    resumed = _resume_policy(tmp_path, 3)
    assert resumed is not None and resumed.version == 42


def test_camera_none_is_a_test_mode_without_a_camera(caplog: pytest.LogCaptureFixture) -> None:
    cfg = CompanionConfig()
    cfg = cfg.model_copy(update={"perception": cfg.perception.model_copy(update={"camera": "none"})})
    with caplog.at_level("WARNING"):
        assert open_run_camera(cfg, None, None) is None  # type: ignore[arg-type]  # the link is never asked
    assert "not visible" in caplog.text


def test_auto_camera_without_a_stream_says_how_to_fly_without_one() -> None:
    with pytest.raises(CameraError, match='"none"'):
        open_camera("auto", auto_uri=None)


def _record(episode: int, success: bool | None) -> EpisodeRecord:
    return EpisodeRecord(episode, "demonstration", 0, 10, 10, 0, 0.0, (), "touchdown", success, 0.1, None, None, 10,
                         1.0, 1.0)


def test_the_summary_says_unknown_where_success_cannot_be_judged(tmp_path: Path) -> None:
    unknown = RunResult(tmp_path, [_record(0, None), _record(1, None)]).summary()
    assert unknown["successes"] is None and unknown["success_rate"] is None and unknown["success_unknown"] == 2
    mixed = RunResult(tmp_path, [_record(0, True), _record(1, False), _record(2, None)]).summary()
    assert mixed["successes"] == 1 and mixed["success_rate"] == 0.5 and mixed["success_unknown"] == 1


def test_lockstep_needs_the_dialects_frame_marker() -> None:
    check_lockstep(PX4, True)
    check_lockstep(ARDUPILOT, False)
    with pytest.raises(ConfigError, match="lockstep needs a frame marker"):
        check_lockstep(ARDUPILOT, True)


def test_ctrl_c_leaves_the_vehicle_safe_before_the_link_closes(tmp_path: Path) -> None:
    """Ctrl-C after the first episode: the run unwinds through the end-of-run policy."""
    import contextlib

    from companion.app import Vehicle
    from tests.control.test_sequences import DialectLink
    from tests.control.test_session import FakeSimulator

    link = DialectLink(PX4)
    closed: list[str] = []

    @contextlib.contextmanager
    def opener(cfg, opts, lockstep, run_dir):  # type: ignore[no-untyped-def]
        try:
            yield Vehicle(link, FakeSimulator(link), None)  # type: ignore[arg-type]  # a vehicle not started here
        finally:
            closed.append(link.calls[-1])

    def interrupt(record) -> None:  # type: ignore[no-untyped-def]
        raise KeyboardInterrupt

    cfg = CompanionConfig()
    cfg = cfg.model_copy(update={"session": cfg.session.model_copy(update={"max_steps": 30, "end_of_run": "hold"})})
    opts = RunOptions(pilot="none", condition="eval", episodes=3, run_dir=tmp_path / "run", lockstep=True, learn=False)
    with pytest.raises(KeyboardInterrupt):
        run_episodes(cfg, opts, on_episode=interrupt, vehicle=opener)
    assert closed == ["mode AUTO.LOITER"]  # held (the configured policy), then the link closed


def test_an_unknown_pilot_or_connection_leaves_no_run_folder(tmp_path: Path) -> None:
    run_dir = tmp_path / "runs" / "r"
    with pytest.raises(ConfigError, match="unknown pilot"):
        run_episodes(CompanionConfig(), RunOptions(pilot="bob", episodes=1, run_dir=run_dir))
    with pytest.raises(ConfigError, match="unknown scheme 'bogus'"):
        run_episodes(CompanionConfig(), RunOptions(connection="bogus://x", episodes=1, run_dir=run_dir))
    assert list(tmp_path.iterdir()) == []


def _failing_opener(error: Exception):  # type: ignore[no-untyped-def]
    """A vehicle that fails to open after the run folder exists (a link that never answers)."""
    import contextlib

    @contextlib.contextmanager
    def opener(cfg, opts, lockstep, run_dir):  # type: ignore[no-untyped-def]
        (run_dir / "session.tlog").touch()  # opened, nothing received
        raise error
        yield  # pragma: no cover

    return opener


def test_a_run_that_fails_before_flying_removes_the_folders_it_made(tmp_path: Path) -> None:
    run_dir = tmp_path / "runs" / "new"
    opts = RunOptions(pilot="none", condition="eval", episodes=1, run_dir=run_dir, learn=False)
    with pytest.raises(ConfigError, match="no heartbeat"):
        run_episodes(CompanionConfig(), opts, vehicle=_failing_opener(ConfigError("no heartbeat")))
    assert list(tmp_path.iterdir()) == []  # runs/ was made for this run too


def test_a_failed_start_keeps_a_folder_that_existed_or_holds_data(tmp_path: Path) -> None:
    kept = tmp_path / "kept"
    kept.mkdir()
    opts = RunOptions(pilot="none", condition="eval", episodes=1, run_dir=kept, learn=False)
    with pytest.raises(ConfigError):
        run_episodes(CompanionConfig(), opts, vehicle=_failing_opener(ConfigError("no heartbeat")))
    assert kept.is_dir()

    import contextlib

    @contextlib.contextmanager
    def telemetry_then_error(cfg, opts, lockstep, run_dir):  # type: ignore[no-untyped-def]
        (run_dir / "session.tlog").write_bytes(b"\xfd" * 40)  # something came in: worth keeping
        raise ConfigError("camera failed")
        yield  # pragma: no cover

    fresh = tmp_path / "fresh"
    opts = RunOptions(pilot="none", condition="eval", episodes=1, run_dir=fresh, learn=False)
    with pytest.raises(ConfigError, match="camera failed"):
        run_episodes(CompanionConfig(), opts, vehicle=telemetry_then_error)
    assert (fresh / "session.tlog").stat().st_size == 40
