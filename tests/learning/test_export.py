"""``col export``: the ONNX graph computes what the torch policy computes (to 1e-5 on 1,000
observations), at the opset asked for; the npz export is a checkpoint that flies the same."""

from __future__ import annotations

import inspect
import json
import stat
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from companion.cli import app, export_cmd
from companion.config import LearnerConfig
from companion.errors import ConfigError
from companion.learning.checkpoint import load_checkpoint, save_checkpoint
from companion.learning.export import DEFAULT_OPSET, check_opset, export_checkpoint
from companion.learning.policy import Normalisation, PolicyNet
from tests.learning.test_checkpoint import umask

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")


def trained_like_policy(seed: int = 3) -> PolicyNet:
    """A torch policy whose layers are neither saturated nor dead: a fair test of the graph."""
    rng = np.random.default_rng(seed)
    norm = Normalisation(rng.normal(0.0, 3.0, 15), rng.uniform(0.2, 5.0, 15))
    return PolicyNet(normalisation=norm, init_std=0.12, generator=torch.Generator().manual_seed(seed))


def observations(net: PolicyNet, n: int, seed: int = 4) -> np.ndarray:
    """``n`` raw observations spread over twice the normalisation's range."""
    norm = net.normalisation()
    z = np.random.default_rng(seed).normal(0.0, 2.0, (n, 15))
    return (norm.mean + z * norm.std).astype(np.float32)


@pytest.fixture
def checkpoint(tmp_path: Path) -> tuple[Path, PolicyNet]:
    net = trained_like_policy()
    path = save_checkpoint(tmp_path / "episode_004.npz", net, LearnerConfig(), dataset_size=120, episode=4,
                           condition="col")
    return path, net


def run_onnx(path: Path, obs: np.ndarray) -> np.ndarray:
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return np.asarray(session.run(["actions"], {"obs": obs})[0])


def test_onnx_matches_the_torch_policy_on_1000_observations(checkpoint: tuple[Path, PolicyNet]) -> None:
    path, net = checkpoint
    written = export_checkpoint(path, "onnx")
    assert written == path.with_suffix(".onnx")
    obs = observations(net, 1000)
    with torch.no_grad():
        expected = net(torch.from_numpy(obs)).numpy()
    got = run_onnx(written, obs)
    assert got.shape == (1000, 4) and got.dtype == np.float32
    assert float(np.max(np.abs(got - expected))) <= 1e-5
    assert np.std(expected) > 0.1  # the policy's outputs vary: the comparison means something
    assert float(np.max(np.abs(got - load_checkpoint(path)[0].act(obs)))) <= 1e-5


def test_onnx_one_observation_batch_and_metadata(checkpoint: tuple[Path, PolicyNet], tmp_path: Path) -> None:
    path, net = checkpoint
    written = export_checkpoint(path, "onnx", tmp_path / "out" / "policy.onnx", opset=13)
    model = onnx.load(str(written))
    assert [o.version for o in model.opset_import if o.domain in ("", "ai.onnx")] == [13]
    props = {p.key: p.value for p in model.metadata_props}
    assert json.loads(props["action_names"]) == ["roll", "pitch", "yaw", "throttle"]
    assert len(json.loads(props["obs_names"])) == 15 and props["episode"] == "4"
    one = observations(net, 1)
    assert np.allclose(run_onnx(written, one), load_checkpoint(path)[0].act(one), atol=1e-5)


def test_bad_opset_and_format_are_refused(checkpoint: tuple[Path, PolicyNet]) -> None:
    path, _ = checkpoint
    with pytest.raises(ConfigError, match="opset 12"):
        export_checkpoint(path, "onnx", opset=12)
    with pytest.raises(ConfigError, match="format"):
        export_checkpoint(path, "tflite")


def test_npz_export_is_a_checkpoint_that_acts_the_same(checkpoint: tuple[Path, PolicyNet]) -> None:
    path, net = checkpoint
    written = export_checkpoint(path, "npz")
    assert written.name == "episode_004.export.npz"
    original, _ = load_checkpoint(path)
    exported, meta = load_checkpoint(written)
    obs = observations(net, 50)
    assert np.array_equal(exported.act(obs), original.act(obs))
    assert meta.episode == 4 and meta.extra["exported_from"] == "episode_004.npz"


def test_cli_export_prints_what_it_wrote_and_fails_clearly(checkpoint: tuple[Path, PolicyNet],
                                                           tmp_path: Path) -> None:
    path, _ = checkpoint
    runner = CliRunner()
    done = runner.invoke(app, ["export", str(path), "--format", "onnx", "--out", str(tmp_path / "p.onnx")])
    assert done.exit_code == 0, done.output
    assert json.loads(done.output.strip().splitlines()[-1]) == {"format": "onnx", "opset": DEFAULT_OPSET,
                                                                 "path": str(tmp_path / "p.onnx")}
    missing = runner.invoke(app, ["export", str(tmp_path / "nope.npz")])
    assert missing.exit_code == 2 and "does not exist" in missing.output
    assert inspect.signature(export_cmd).parameters["opset"].default == DEFAULT_OPSET


@pytest.mark.parametrize("fmt", ["onnx", "npz"])
def test_exports_are_readable_by_others_under_the_usual_umask(checkpoint: tuple[Path, PolicyNet],
                                                              tmp_path: Path, fmt: str) -> None:
    """The Dockerfile's example mounts the exported policy read-only for uid 10001."""
    path, _ = checkpoint
    with umask(0o022):
        written = export_checkpoint(path, fmt, tmp_path / "out" / f"policy.{fmt}")
    assert stat.S_IMODE(written.stat().st_mode) == 0o644
    assert sorted(p.name for p in written.parent.iterdir()) == [written.name]  # no temporary left


def test_without_onnx_the_hint_installs_from_the_project_not_a_package_index(monkeypatch) -> None:
    """``cycle-of-learning`` is not on PyPI: the hint names the checkout (or a built wheel)."""
    monkeypatch.setitem(sys.modules, "onnx", None)  # import onnx raises ImportError
    with pytest.raises(ConfigError) as err:
        check_opset(DEFAULT_OPSET)
    assert "pip install '.[onnx]'" in str(err.value) and "pip install 'cycle-of-learning" not in str(err.value)
