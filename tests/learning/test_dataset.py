"""HumanDataset: the paper's CSV, crash safety, resume, torn lines, lock-free views."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from companion.errors import DatasetCorrupt
from companion.learning.dataset import HumanDataset, csv_header, load_csv
from companion.msg.observation import OBS_NAMES
from companion.msg.sample import Sample, Source


def _sample(i: int, episode: int = 0, source: Source = Source.DEMONSTRATION) -> Sample:
    """Row i is recognisable from its values: obs[0] == i, action[0] == i / 10_000."""
    obs = np.full(15, 0.5, np.float32)
    obs[0] = i
    return Sample(episode, i, i * 0.0952, source, obs, np.array([i / 10_000, -0.25, 0.0, 1.0]))


def _check_rows(obs: np.ndarray, actions: np.ndarray) -> None:
    n = obs.shape[0]
    np.testing.assert_array_equal(obs[:, 0], np.arange(n, dtype=np.float32))
    np.testing.assert_array_equal(actions[:, 0], (np.arange(n) / 10_000).astype(np.float32))


def test_header_is_the_papers_columns(tmp_path: Path) -> None:
    path = tmp_path / "run" / "d.csv"  # the folder is made if missing
    HumanDataset(path).close()
    header = path.read_text().splitlines()[0].split(",")
    assert header[:4] == ["episode", "step", "time_s", "source"]
    assert header[4:19] == list(OBS_NAMES)
    assert header[19:] == ["roll", "pitch", "yaw", "throttle"]
    assert tuple(header) == csv_header()


def test_round_trip_is_exact(tmp_path: Path, rng: np.random.Generator) -> None:
    path = tmp_path / "d.csv"
    samples = [Sample(2, i, 0.1 * i, Source.INTERVENTION, rng.normal(size=15),
                      rng.uniform(-1, 1, 4)) for i in range(50)]
    with HumanDataset(path) as ds:
        for s in samples:
            ds.append(s)
    loaded = load_csv(path)
    assert loaded.report.rows == 50 and loaded.report.skipped_rows == 0
    np.testing.assert_array_equal(loaded.obs, np.stack([s.obs for s in samples]))
    np.testing.assert_array_equal(loaded.actions, np.stack([s.action for s in samples]))
    assert set(loaded.source) == {Source.INTERVENTION} and list(loaded.step) == list(range(50))


def test_resume_keeps_rows_and_appends(tmp_path: Path) -> None:
    path = tmp_path / "d.csv"
    with HumanDataset(path) as ds:
        ds.extend(_sample(i, episode=0) for i in range(10))
    with HumanDataset(path) as ds:
        assert len(ds) == 10 and ds.last_episode == 0
        ds.extend(_sample(i, episode=1, source=Source.INTERVENTION) for i in range(10, 15))
        assert ds.counts == {Source.DEMONSTRATION: 10, Source.INTERVENTION: 5}
    loaded = load_csv(path)
    _check_rows(loaded.obs, loaded.actions)
    assert loaded.obs.shape[0] == 15 and path.read_text().count("episode,") == 1


def test_torn_last_line_is_skipped_reported_and_cut_on_resume(tmp_path: Path, caplog) -> None:
    path = tmp_path / "d.csv"
    with HumanDataset(path) as ds:
        ds.extend(_sample(i) for i in range(5))
    with path.open("ab") as fh:
        fh.write(b"0,5,0.476,demonstration,5,0.5,0.")  # a crash inside a write
    with caplog.at_level(logging.WARNING):
        loaded = load_csv(path)
    assert loaded.report.rows == 5 and loaded.report.skipped_rows == 1
    assert "torn last line" in loaded.report.problems[0] and "torn last line" in caplog.text
    with HumanDataset(path) as ds:
        assert len(ds) == 5 and ds.load_report.skipped_rows == 1
        ds.append(_sample(5))
    clean = load_csv(path)
    assert clean.report.skipped_rows == 0
    _check_rows(clean.obs, clean.actions)


def test_unreadable_last_line_skipped_but_middle_line_is_corruption(tmp_path: Path) -> None:
    path = tmp_path / "d.csv"
    with HumanDataset(path) as ds:
        ds.extend(_sample(i) for i in range(3))
    good = path.read_bytes()
    path.write_bytes(good + b"\x00\x00\x00\n")
    assert load_csv(path).report.skipped_rows == 1
    lines = good.split(b"\n")
    lines[2] = lines[2].replace(b"demonstration", b"banana")
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(DatasetCorrupt, match="line 3"):
        load_csv(path)


def test_wrong_header_refused_with_the_difference(tmp_path: Path) -> None:
    path = tmp_path / "d.csv"
    header = list(csv_header())
    header[3] = "who"
    path.write_text(",".join(header) + "\n")
    with pytest.raises(DatasetCorrupt, match="column 3 is 'who', expected 'source'"):
        HumanDataset(path)
    path.write_text("a,b\n")
    with pytest.raises(DatasetCorrupt):
        load_csv(path)


def test_torn_header_means_empty(tmp_path: Path) -> None:
    path = tmp_path / "d.csv"
    path.write_text("episode,step,ti")
    with HumanDataset(path) as ds:
        assert len(ds) == 0
        ds.append(_sample(0))
    assert load_csv(path).report.rows == 1


def test_invalid_samples_refused() -> None:
    ds = HumanDataset(None)
    with pytest.raises(ValueError, match="non-finite"):
        Sample(0, 0, 0.0, Source.DEMONSTRATION, np.full(15, np.nan), np.zeros(4))
    with pytest.raises(ValueError, match=r"\[-1, 1\]"):
        Sample(0, 0, 0.0, Source.DEMONSTRATION, np.zeros(15), np.array([0, 0, 0, 1.5]))
    with pytest.raises(ValueError):
        Sample(0, 0, 0.0, "teleport", np.zeros(15), np.zeros(4))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="14 values"):
        ds.append(Sample(0, 0, 0.0, Source.DEMONSTRATION, np.zeros(14), np.zeros(4)))
    assert len(ds) == 0


def test_views_are_read_only_and_unaffected_by_growth() -> None:
    ds = HumanDataset(None, chunk_rows=4)
    ds.extend(_sample(i) for i in range(3))
    old = ds.view()
    old_obs = old.obs.copy()
    ds.extend(_sample(i) for i in range(3, 100))  # grows the arrays several times
    assert len(old) == 3 and len(ds.view()) == 100
    np.testing.assert_array_equal(old.obs, old_obs)
    with pytest.raises(ValueError):
        old.obs[0, 0] = 42.0
    _check_rows(ds.view().obs, ds.view().actions)


def test_concurrent_append_and_read_consistent() -> None:
    ds = HumanDataset(None, chunk_rows=16)
    n_rows, errors = 3000, []

    def writer() -> None:
        for i in range(n_rows):
            ds.append(_sample(i))

    def reader() -> None:
        last = 0
        while last < n_rows:
            view = ds.view()
            try:
                assert len(view) >= last
                _check_rows(view.obs, view.actions)
            except AssertionError as exc:
                errors.append(exc)
                return
            last = len(view)

    threads = [threading.Thread(target=writer), threading.Thread(target=reader)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert not errors and len(ds) == n_rows


def test_wait_for_growth_wakes_on_append() -> None:
    ds = HumanDataset(None)
    timer = threading.Timer(0.05, lambda: ds.append(_sample(0)))
    t0 = time.monotonic()
    timer.start()
    assert ds.wait_for_growth(0, timeout_s=5.0) == 1
    assert time.monotonic() - t0 < 1.0
    assert ds.wait_for_growth(1, timeout_s=0.01) == 1


WRITER = textwrap.dedent("""
    import sys
    import numpy as np
    from companion.learning.dataset import HumanDataset
    from companion.msg.sample import Sample, Source
    ds = HumanDataset(sys.argv[1])
    i = 0
    while True:
        obs = np.full(15, 0.5, np.float32); obs[0] = i
        ds.append(Sample(0, i, i * 0.0952, Source.DEMONSTRATION, obs,
                         np.array([i / 10_000, -0.25, 0.0, 1.0])))
        i += 1
        sys.stdout.write(f"{i}\\n"); sys.stdout.flush()
""")


def test_sigkill_mid_stream_loses_no_flushed_row(tmp_path: Path) -> None:
    path = tmp_path / "d.csv"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE,
                            text=True, cwd=Path(__file__).resolve().parents[2])
    acked = 0
    try:
        assert proc.stdout is not None
        while acked < 400:
            line = proc.stdout.readline()
            assert line, "writer process ended early"
            acked = int(line)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
    assert proc.returncode == -signal.SIGKILL
    loaded = load_csv(path)
    assert loaded.obs.shape[0] >= acked  # every row the writer had returned from is there
    _check_rows(loaded.obs, loaded.actions)
    with HumanDataset(path) as ds:  # and the file resumes cleanly
        assert len(ds) == loaded.obs.shape[0]
