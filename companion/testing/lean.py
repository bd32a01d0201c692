"""An environment in which the packages of the optional extras cannot be imported, as on a lean
install (``pip install .`` in the project's folder, no extras): for tests and benchmarks of the flight runtime
without a second virtual environment.

The block is a ``sitecustomize`` module on ``PYTHONPATH``: it puts a finder at the head of
``sys.meta_path`` that refuses those packages, in the process started with the environment and
in every Python process that one starts (they inherit it), as if they were not installed.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path

NOT_IN_THE_LEAN_INSTALL: tuple[str, ...] = (
    "torch", "stable_baselines3", "gymnasium", "matplotlib", "scipy",  # train
    "mavsdk", "pygame", "onnx", "onnxruntime", "ray",  # mavsdk, gamepad, onnx, cluster
)

_BLOCKER = '''"""Written by companion.testing.lean: refuse {blocked!r} as if not installed."""
import sys

BLOCKED = {blocked!r}


class _NotInstalled:
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {{name!r}} (not in the lean install)", name=name)
        return None


sys.meta_path.insert(0, _NotInstalled())
'''


def lean_env(folder: Path, *, blocked: Iterable[str] = NOT_IN_THE_LEAN_INSTALL,
             base: Mapping[str, str] | None = None, prepend: Iterable[str] = ()) -> dict[str, str]:
    """``base`` (default: this process's environment) with the blocker written into ``folder``
    and put first on ``PYTHONPATH``, then ``prepend`` (e.g. a source checkout)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "sitecustomize.py").write_text(_BLOCKER.format(blocked=tuple(sorted(blocked))))
    env = dict(os.environ if base is None else base)
    parts = [str(folder), *prepend, env.get("PYTHONPATH", "")]
    env["PYTHONPATH"] = os.pathsep.join(p for p in parts if p)
    return env
