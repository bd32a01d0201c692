"""Checkpoints: atomic, self-describing round trip; corrupt or incompatible files refused."""

from __future__ import annotations

import io
import json
import os
import stat
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import torch

from companion.config import LearnerConfig
from companion.errors import CheckpointError
from companion.learning.checkpoint import FORMAT_VERSION, load_checkpoint, save_checkpoint
from companion.learning.policy import Normalisation, PolicyNet, PolicySnapshot
from companion.msg.observation import OBS_NAMES


def _snapshot(rng: np.random.Generator, obs_dim: int = 15) -> PolicySnapshot:
    norm = Normalisation(rng.normal(size=obs_dim), rng.uniform(0.5, 2, size=obs_dim))
    net = PolicyNet(obs_dim, generator=torch.Generator().manual_seed(1), normalisation=norm)
    return net.snapshot(version=321, dataset_size_trained=77)


def _save(path: Path, snap: PolicySnapshot | PolicyNet, **kw) -> Path:
    names = kw.pop("obs_names", OBS_NAMES)
    return save_checkpoint(path, snap, LearnerConfig(seed=5), dataset_size=80, episode=3,
                           condition="CoL", obs_names=names, extra={"pilot": "steady"}, **kw)


def test_round_trip_gives_the_same_actions_and_metadata(tmp_path: Path, rng) -> None:
    snap = _snapshot(rng)
    path = _save(tmp_path / "ep3.npz", snap)
    loaded, meta = load_checkpoint(path)
    x = rng.normal(size=(20, 15))
    np.testing.assert_array_equal(loaded.act(x), snap.act(x))
    np.testing.assert_array_equal(loaded.normalisation.std, snap.normalisation.std)
    assert (loaded.version, loaded.dataset_size_trained) == (321, 77)
    assert meta.format_version == FORMAT_VERSION and meta.obs_names == tuple(OBS_NAMES)
    assert meta.action_names == ("roll", "pitch", "yaw", "throttle")
    assert meta.hidden == (130, 72, 40) and meta.config["seed"] == 5
    assert (meta.dataset_size, meta.episode, meta.condition) == (80, 3, "CoL")
    assert meta.extra == {"pilot": "steady"}
    assert [p.name for p in tmp_path.iterdir()] == ["ep3.npz"]  # no temporary left behind


def test_a_model_can_be_saved_directly(tmp_path: Path, rng) -> None:
    net = PolicyNet(generator=torch.Generator().manual_seed(2))
    loaded, _ = load_checkpoint(_save(tmp_path / "m.npz", net))
    x = rng.normal(size=15).astype(np.float32)
    np.testing.assert_allclose(loaded.act(x), net(torch.from_numpy(x)).detach().numpy(), atol=1e-6)


def test_overwrite_replaces_the_whole_file(tmp_path: Path, rng) -> None:
    path = tmp_path / "c.npz"
    _save(path, _snapshot(rng))
    newer = PolicyNet(generator=torch.Generator().manual_seed(8)).snapshot(version=999)
    _save(path, newer)
    assert load_checkpoint(path)[0].version == 999


@pytest.mark.parametrize("damage", ["truncate", "flip", "garbage", "empty"])
def test_corrupt_files_are_refused_clearly(tmp_path: Path, rng, damage: str) -> None:
    path = _save(tmp_path / "c.npz", _snapshot(rng))
    data = bytearray(path.read_bytes())
    if damage == "truncate":
        data = data[: len(data) // 2]
    elif damage == "flip":
        start = data.find(b"weight_1.npy") + 200  # inside that member's stored bytes
        data[start: start + 8] = bytes(8)
    elif damage == "garbage":
        data = bytearray(b"not a checkpoint at all" * 10)
    else:
        data = bytearray()
    path.write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match=r"corrupt|truncated") as refused:
        load_checkpoint(path)
    assert "pickle" not in str(refused.value)  # never advise loading an unknown file unsafely


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(CheckpointError, match="does not exist"):
        load_checkpoint(tmp_path / "nope.npz")


def _rewrite_metadata(path: Path, change) -> None:
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(arrays["metadata"].tobytes())
    change(meta)
    arrays["metadata"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    path.write_bytes(buf.getvalue())


def test_other_format_version_refused(tmp_path: Path, rng) -> None:
    path = _save(tmp_path / "c.npz", _snapshot(rng))
    _rewrite_metadata(path, lambda m: m.update(format_version=FORMAT_VERSION + 1))
    with pytest.raises(CheckpointError, match="format version 2"):
        load_checkpoint(path)


def test_other_observation_refused(tmp_path: Path, rng) -> None:
    names = [f"f{i}" for i in range(12)]
    path = _save(tmp_path / "c.npz", _snapshot(rng, obs_dim=12), obs_names=names)
    with pytest.raises(CheckpointError, match="takes 12 observation values"):
        load_checkpoint(path)
    assert load_checkpoint(path, obs_dim=12, obs_names=names)[0].obs_dim == 12
    with pytest.raises(CheckpointError, match="same observation layout"):
        load_checkpoint(path, obs_dim=None, obs_names=[f"g{i}" for i in range(12)])


def test_same_size_other_observation_order_refused(tmp_path: Path, rng) -> None:
    path = _save(tmp_path / "c.npz", _snapshot(rng), obs_names=list(reversed(OBS_NAMES)))
    with pytest.raises(CheckpointError, match="same observation layout"):
        load_checkpoint(path)


def test_inconsistent_metadata_refused(tmp_path: Path, rng) -> None:
    path = _save(tmp_path / "c.npz", _snapshot(rng))
    _rewrite_metadata(path, lambda m: m.update(hidden=[130, 72]))
    with pytest.raises(CheckpointError):
        load_checkpoint(path)
    _rewrite_metadata(path, lambda m: m.pop("episode"))
    with pytest.raises(CheckpointError, match="incomplete"):
        load_checkpoint(path)


def test_non_json_extra_refused_before_writing(tmp_path: Path, rng) -> None:
    with pytest.raises(ValueError, match="JSON"):
        save_checkpoint(tmp_path / "c.npz", _snapshot(rng), LearnerConfig(), dataset_size=0,
                        episode=0, condition="Demo", extra={"bad": object()})
    assert not list(tmp_path.iterdir())


def test_file_is_a_plain_zip_without_pickles(tmp_path: Path, rng) -> None:
    path = _save(tmp_path / "c.npz", _snapshot(rng))
    with zipfile.ZipFile(path) as zf:
        assert zf.testzip() is None
        assert "metadata.npy" in zf.namelist()


@contextmanager
def umask(mask: int) -> Iterator[None]:
    """The process umask set to ``mask`` for the block (tests run single-threaded here)."""
    old = os.umask(mask)
    try:
        yield
    finally:
        os.umask(old)


@pytest.mark.parametrize(("mask", "mode"), [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_the_file_mode_follows_the_umask(tmp_path: Path, rng, mask: int, mode: int) -> None:
    """Not mkstemp's 0600: a checkpoint mounted read-only into a container of another uid must
    be readable there, and a user who wants it private says so with the umask."""
    with umask(mask):
        path = _save(tmp_path / "shared.npz", _snapshot(rng))
        _save(path, _snapshot(rng))  # an overwrite gets the same mode
    assert stat.S_IMODE(path.stat().st_mode) == mode
    assert [p.name for p in tmp_path.iterdir()] == ["shared.npz"]
