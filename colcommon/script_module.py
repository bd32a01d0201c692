"""A script that is not part of a package (a results folder's run.py, a bench), loaded as a module.

Results folders keep their runners beside their results, where no package reaches them; their
tests and the runners that build on each other load them by path, under a name of their own so
that two files both called ``run.py`` are never taken for one another.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType


def load_script(path: Path, name: str) -> ModuleType:
    """The module of the script at ``path``, registered as ``name`` (dataclasses look their
    module up in ``sys.modules``); loaded once, the same module afterwards."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"{path}: not a Python script")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module
