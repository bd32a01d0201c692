"""The ``col`` command's entry point: commands that make results run under the numeric pin.

``col experiment``, ``col eval``, ``col ppo`` and ``col finetune`` write numbers that someone
else must be able to rerun byte for byte, so they re-execute themselves with the project's
numeric profile before any library loads (:mod:`colcommon.numeric_env`); every worker and SITL
process they start inherits it. ``col experiment --verify DIR`` reruns in the environment DIR's
``environment.jsonl`` recorded instead (the profile, or the CPU's own kernels with the OpenBLAS
core type that run loaded), where this CPU can run it. Flying, the console and the rest keep
the CPU's own kernels.
"""

from __future__ import annotations

import platform
import sys
from pathlib import Path

from colcommon.numeric_env import (
    OPT_OUT,
    PROFILE,
    can_run_environ,
    cpu_flags,
    ensure_environ,
    ensure_pinned,
    environ_of_record,
    read_records,
)

PINNED_COMMANDS = frozenset({"experiment", "eval", "ppo", "finetune"})


def command_of(argv: list[str]) -> str | None:
    """The subcommand named in ``argv`` (``col [--opt] NAME ...``), or None."""
    return next((a for a in argv[1:] if not a.startswith("-")), None)


def verified_folder(argv: list[str]) -> Path | None:
    """The folder of ``col experiment --verify DIR`` (or ``--verify=DIR``), else None."""
    for i, arg in enumerate(argv):
        if arg == "--verify" and i + 1 < len(argv):
            return Path(argv[i + 1])
        if arg.startswith("--verify="):
            return Path(arg.split("=", 1)[1])
    return None


def _rerun_as_recorded(argv: list[str]) -> bool:
    """``--verify`` reruns trials in the environment their folder recorded, where this CPU can.
    False when there is no usable record (then the profile applies)."""
    folder = verified_folder(argv)
    records = read_records(folder) if folder is not None else []
    wanted = environ_of_record(records[0]) if records else None
    if wanted is None:
        return False
    if not can_run_environ(wanted, platform.machine(), cpu_flags()):
        print(f"col: this CPU cannot run the kernels {folder} was made with "
              f"({wanted.get('OPENBLAS_CORETYPE', PROFILE)}); its trials will not rerun identically", file=sys.stderr)
        return False
    ensure_environ(argv, wanted)
    return True


def main() -> None:
    command = command_of(sys.argv)
    if command in PINNED_COMMANDS and not (command == "experiment" and _rerun_as_recorded(sys.argv)):
        reason = ensure_pinned(sys.argv)  # returns only if already pinned, or if it cannot be
        if reason is not None:
            print(f"col: numeric profile {PROFILE} not applied ({reason}); "
                  f"unset {OPT_OUT} on an x86-64 CPU with AVX2 to apply it", file=sys.stderr)
    from companion.cli import app

    app()
