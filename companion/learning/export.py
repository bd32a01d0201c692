"""A policy for other runtimes: ONNX (checked with ONNX Runtime; TensorRT untested) and a plain NumPy archive.

The ONNX graph is built from the frozen snapshot with ``onnx.helper`` (no torch, so the lean
install plus the ``onnx`` extra can export): input ``obs`` ``float32 [batch, obs_dim]`` in the
observation's raw units -> ``Sub(obs_mean)`` -> ``Div(obs_std)`` -> ``Gemm`` + ``Relu`` per
hidden layer -> ``Gemm`` -> ``Tanh`` -> output ``actions`` ``float32 [batch, 4]`` (roll, pitch,
yaw, throttle in (-1, 1)). Every operator is in the default domain and unchanged since opset
13, so any opset from :data:`MIN_OPSET` to the installed ``onnx``'s newest works;
:data:`DEFAULT_OPSET` is 17. The observation and action names, the normalisation and the
checkpoint's metadata travel as the model's metadata properties.

The ``npz`` export is the checkpoint format itself (:mod:`companion.learning.checkpoint`),
rewritten from what was loaded and validated, so ``col fly --checkpoint`` and ``numpy.load``
read it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from companion import install_hint
from companion.config import LearnerConfig
from companion.errors import ConfigError
from companion.learning.checkpoint import (
    CheckpointMeta,
    load_checkpoint,
    save_checkpoint,
    write_atomically,
)
from companion.learning.snapshot import PolicySnapshot
from companion.msg.command import ACTION_NAMES

if TYPE_CHECKING:
    import onnx

ExportFormat = Literal["onnx", "npz"]
FORMATS: tuple[str, ...] = ("onnx", "npz")
DEFAULT_OPSET = 17
MIN_OPSET = 13


def _onnx() -> Any:
    try:
        import onnx
    except ImportError:
        raise ConfigError(f"ONNX export needs the onnx extra: {install_hint('onnx')}") from None
    return onnx


def check_opset(opset: int) -> int:
    """``opset`` if the graph can be written in it with the installed onnx; a clear error if not."""
    newest = int(_onnx().defs.onnx_opset_version())
    if not MIN_OPSET <= opset <= newest:
        raise ConfigError(f"opset {opset} is outside {MIN_OPSET}..{newest} (the graph needs opset 13 "
                          f"operators; the installed onnx writes up to {newest})")
    return opset


def onnx_model(snapshot: PolicySnapshot, opset: int = DEFAULT_OPSET,
               metadata: dict[str, str] | None = None) -> onnx.ModelProto:
    """The snapshot as a checked ONNX model (see the module docstring for the graph)."""
    onnx = _onnx()
    helper, tp = onnx.helper, onnx.TensorProto
    check_opset(opset)
    inits = [onnx.numpy_helper.from_array(snapshot.normalisation.mean, "obs_mean"),
             onnx.numpy_helper.from_array(snapshot.normalisation.std, "obs_std")]
    nodes = [helper.make_node("Sub", ["obs", "obs_mean"], ["centred"]),
             helper.make_node("Div", ["centred", "obs_std"], ["h0"])]
    last = len(snapshot.weights) - 1
    for i, (w, b) in enumerate(zip(snapshot.weights, snapshot.biases, strict=True)):
        inits += [onnx.numpy_helper.from_array(np.ascontiguousarray(w), f"weight_{i}"),
                  onnx.numpy_helper.from_array(np.ascontiguousarray(b), f"bias_{i}")]
        out = f"z{i}" if i == last else f"a{i}"
        nodes.append(helper.make_node("Gemm", [f"h{i}", f"weight_{i}", f"bias_{i}"], [out], transB=1))
        if i < last:
            nodes.append(helper.make_node("Relu", [out], [f"h{i + 1}"]))
    nodes.append(helper.make_node("Tanh", [f"z{last}"], ["actions"]))
    graph = helper.make_graph(
        nodes, "col_policy",
        [helper.make_tensor_value_info("obs", tp.FLOAT, ["batch", snapshot.obs_dim])],
        [helper.make_tensor_value_info("actions", tp.FLOAT, ["batch", len(ACTION_NAMES)])],
        initializer=inits,
    )
    model = helper.make_model_gen_version(graph, opset_imports=[helper.make_opsetid("", opset)],
                                          producer_name="cycle-of-learning")
    helper.set_model_props(model, metadata or {})
    onnx.checker.check_model(model, full_check=True)
    return model


def _metadata(meta: CheckpointMeta) -> dict[str, str]:
    return {
        "obs_names": json.dumps(list(meta.obs_names)),
        "action_names": json.dumps(list(meta.action_names)),
        "hidden": json.dumps(list(meta.hidden)),
        "normalisation": "inside the graph: (obs - obs_mean) / obs_std",
        "episode": str(meta.episode),
        "condition": meta.condition,
        "policy_version": str(meta.version),
        "dataset_size": str(meta.dataset_size),
        "checkpoint_created_utc": meta.created_utc,
    }


def default_output(checkpoint: Path, fmt: str) -> Path:
    """Beside the checkpoint: ``episode_007.onnx`` or ``episode_007.export.npz``."""
    return checkpoint.with_suffix(".onnx" if fmt == "onnx" else ".export.npz")


def export_checkpoint(checkpoint: Path, fmt: str, out: Path | None = None,
                      opset: int = DEFAULT_OPSET) -> Path:
    """Load ``checkpoint`` (validated as for flying) and write it as ``fmt``; the path written."""
    if fmt not in FORMATS:
        raise ConfigError(f"unknown export format {fmt!r}; use one of {', '.join(FORMATS)}")
    snapshot, meta = load_checkpoint(checkpoint, obs_dim=None, obs_names=None)
    target = out or default_output(checkpoint, fmt)
    if target.resolve() == checkpoint.resolve():
        raise ConfigError(f"the export would overwrite its checkpoint {checkpoint}; pass another --out")
    if fmt == "npz":
        config = LearnerConfig.model_validate(meta.config)
        return save_checkpoint(target, snapshot, config, dataset_size=meta.dataset_size, episode=meta.episode,
                               condition=meta.condition, obs_names=meta.obs_names,
                               extra={**meta.extra, "exported_from": checkpoint.name})
    model = onnx_model(snapshot, check_opset(opset), _metadata(meta))
    return write_atomically(target, model.SerializeToString())
