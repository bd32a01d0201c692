"""Policy checkpoints: one self-describing file per episode, written atomically.

Format (``FORMAT_VERSION`` 1): a NumPy ``.npz`` archive (zip; every member CRC-checked on
read, no pickles) holding ``weight_<i>`` ``(out, in)`` and ``bias_<i>`` float32 arrays,
``obs_mean``/``obs_std`` (an ensemble adds ``member_weight_<i>`` ``(K, out, in)`` and
``member_bias_<i>``, with member 0 as ``weight_<i>``), and ``metadata`` - UTF-8 JSON as a uint8 array with the format name
and version, observation and action names, hidden sizes, activations, the learner config,
snapshot version, dataset size, episode, condition, creation time and free-form ``extra``.

Writing goes to a temporary file in the same directory, is fsync'ed, then ``os.replace``'d
over the target: a reader sees the old file or the new one, never half of one. The file's
mode is 0666 less the umask, as for any file the process writes (0644 under the usual 022).
"""

from __future__ import annotations

import io
import json
import os
import secrets
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from companion.config import LearnerConfig
from companion.errors import CheckpointError
from companion.learning.ensemble import EnsembleSnapshot
from companion.learning.snapshot import Normalisation, PolicySnapshot
from companion.msg.command import ACTION_NAMES
from companion.msg.observation import OBS_DIM, OBS_NAMES

if TYPE_CHECKING:  # reading and writing checkpoints needs no torch
    from companion.learning.policy import PolicyNet

FORMAT_NAME = "col-policy"
FORMAT_VERSION = 1


@dataclass(frozen=True)
class CheckpointMeta:
    """Everything in a checkpoint besides the weights."""

    format_version: int
    obs_names: tuple[str, ...]
    action_names: tuple[str, ...]
    hidden: tuple[int, ...]
    config: dict[str, Any]
    dataset_size: int
    episode: int
    condition: str
    version: int
    dataset_size_trained: int
    created_utc: str
    extra: dict[str, Any] = field(default_factory=dict)


def save_checkpoint(
    path: str | Path,
    policy: PolicySnapshot | PolicyNet,
    config: LearnerConfig,
    *,
    dataset_size: int,
    episode: int,
    condition: str,
    obs_names: Sequence[str] = OBS_NAMES,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write ``policy`` and its description to ``path`` atomically; returns the path.

    ``extra`` must be JSON-serialisable (e.g. pilot name, success so far).
    """
    snap = policy if isinstance(policy, PolicySnapshot) else policy.snapshot()
    if len(obs_names) != snap.obs_dim:
        raise ValueError(f"{len(obs_names)} observation names for a policy of {snap.obs_dim} inputs")
    meta = _metadata(snap, config, dataset_size, episode, condition, obs_names, extra or {})
    arrays = {f"weight_{i}": w for i, w in enumerate(snap.weights)}
    arrays |= {f"bias_{i}": b for i, b in enumerate(snap.biases)}
    arrays |= {"obs_mean": snap.normalisation.mean, "obs_std": snap.normalisation.std}
    if isinstance(snap, EnsembleSnapshot):
        arrays |= {f"member_weight_{i}": w for i, w in enumerate(snap.member_weights)}
        arrays |= {f"member_bias_{i}": b for i, b in enumerate(snap.member_biases)}
        meta["ensemble_members"] = snap.members
    arrays["metadata"] = np.frombuffer(json.dumps(meta, indent=1).encode(), dtype=np.uint8)
    buf = io.BytesIO()
    np.savez(buf, allow_pickle=False, **cast(dict[str, Any], arrays))
    return write_atomically(Path(path), buf.getvalue())


def _metadata(snap: PolicySnapshot, config: LearnerConfig, dataset_size: int, episode: int,
              condition: str, obs_names: Sequence[str], extra: dict[str, Any]) -> dict[str, Any]:
    meta = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "obs_names": list(obs_names),
        "action_names": list(ACTION_NAMES),
        "hidden": list(snap.hidden),
        "activation": "relu",
        "output": "tanh",
        "normalisation": "(obs - obs_mean) / obs_std",
        "config": config.model_dump(mode="json"),
        "dataset_size": int(dataset_size),
        "episode": int(episode),
        "condition": str(condition),
        "version": snap.version,
        "dataset_size_trained": snap.dataset_size_trained,
        "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "extra": extra,
    }
    try:
        json.dumps(meta)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"checkpoint metadata must be JSON-serialisable: {exc}") from exc
    return meta


def write_atomically(path: Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` so that a reader sees the old file or the new one, never half.

    The file gets the permissions of any file the process creates (0666 less the umask), not
    the 0600 of :func:`tempfile.mkstemp`: a checkpoint is handed to other users, for example
    mounted read-only into a container that runs as another uid.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = _create_temporary(path)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)  # make the rename itself durable
    finally:
        os.close(dir_fd)
    return path


def _create_temporary(path: Path) -> tuple[int, Path]:
    """A new, exclusively created file beside ``path``, mode 0666 filtered by the umask (the
    kernel applies it; reading the umask with ``os.umask`` would race other threads)."""
    for _ in range(100):
        tmp = path.parent / f".{path.name}.{secrets.token_hex(4)}.tmp"
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666), tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"no free temporary name beside {path}")


def load_checkpoint(path: str | Path, *, obs_dim: int | None = OBS_DIM,
                    obs_names: Sequence[str] | None = OBS_NAMES
                    ) -> tuple[PolicySnapshot, CheckpointMeta]:
    """Read a checkpoint; CheckpointError if it is missing, corrupt or incompatible.

    ``obs_dim`` and ``obs_names`` (None: accept any) must match the file's: a policy trained
    on another observation layout would fly nonsense.
    """
    p = Path(path)
    arrays = _read_arrays(p)
    meta = _parse_metadata(p, arrays)
    if obs_dim is not None and len(meta.obs_names) != obs_dim:
        raise CheckpointError(
            f"{p}: policy takes {len(meta.obs_names)} observation values, this program gives "
            f"{obs_dim}; use a checkpoint trained with the same observation"
        )
    if obs_names is not None and tuple(obs_names) != meta.obs_names:
        raise CheckpointError(
            f"{p}: trained on observations {list(meta.obs_names)}, this program uses "
            f"{list(obs_names)}; use a checkpoint made with the same observation layout"
        )
    return _snapshot(p, arrays, meta), meta


def _read_arrays(p: Path) -> dict[str, np.ndarray]:
    if not p.is_file():
        raise CheckpointError(f"checkpoint {p} does not exist; pass a policy written by col fly, col demo or "
                              "col experiment (RUN/checkpoints/episode_NNN.npz)")
    try:
        with np.load(p, allow_pickle=False) as npz:
            return {name: npz[name] for name in npz.files}
    except ValueError as exc:  # not numpy's advice to allow pickles: a checkpoint never needs them
        raise CheckpointError(f"checkpoint {p} is corrupt or truncated (not an .npz archive of plain "
                              "arrays); use another one") from exc
    except (OSError, EOFError, KeyError, zipfile.BadZipFile) as exc:
        raise CheckpointError(f"checkpoint {p} is corrupt or truncated ({exc}); use another one") from exc


def _parse_metadata(p: Path, arrays: dict[str, np.ndarray]) -> CheckpointMeta:
    try:
        meta = json.loads(arrays["metadata"].tobytes().decode("utf-8"))
    except (KeyError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CheckpointError(f"checkpoint {p} has no readable metadata ({exc}); use another one") from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMAT_NAME:
        raise CheckpointError(f"{p} is not a {FORMAT_NAME} checkpoint")
    if meta.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(
            f"{p} has checkpoint format version {meta.get('format_version')}; this program "
            f"reads version {FORMAT_VERSION}: load it with the version that wrote it"
        )
    try:
        return CheckpointMeta(
            FORMAT_VERSION, tuple(meta["obs_names"]), tuple(meta["action_names"]),
            tuple(int(h) for h in meta["hidden"]), dict(meta["config"]), int(meta["dataset_size"]),
            int(meta["episode"]), str(meta["condition"]), int(meta["version"]),
            int(meta["dataset_size_trained"]), str(meta["created_utc"]), dict(meta.get("extra", {})),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"checkpoint {p} metadata is incomplete ({exc}); use another one") from exc


def _snapshot(p: Path, arrays: dict[str, np.ndarray], meta: CheckpointMeta) -> PolicySnapshot:
    if meta.action_names != ACTION_NAMES:
        raise CheckpointError(f"{p}: actions {list(meta.action_names)}, expected {list(ACTION_NAMES)}")
    n_layers = len(meta.hidden) + 1
    try:
        weights = tuple(arrays[f"weight_{i}"] for i in range(n_layers))
        biases = tuple(arrays[f"bias_{i}"] for i in range(n_layers))
        norm = Normalisation(arrays["obs_mean"], arrays["obs_std"])
        snap = PolicySnapshot(weights, biases, norm, meta.version, meta.dataset_size_trained)
        if "member_weight_0" in arrays:
            snap = EnsembleSnapshot.stack([arrays[f"member_weight_{i}"] for i in range(n_layers)],
                                          [arrays[f"member_bias_{i}"] for i in range(n_layers)],
                                          norm, meta.version, meta.dataset_size_trained)
    except (KeyError, ValueError) as exc:
        raise CheckpointError(f"checkpoint {p} weights are inconsistent ({exc}); use another one") from exc
    if snap.obs_dim != len(meta.obs_names) or snap.hidden != meta.hidden:
        raise CheckpointError(f"checkpoint {p}: weights do not match the described shapes")
    return snap
