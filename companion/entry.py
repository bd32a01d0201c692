"""The ``col`` command's entry point: commands that make results run under the numeric pin.

``col experiment``, ``col eval``, ``col ppo`` and ``col finetune`` write numbers that someone
else must be able to rerun byte for byte, so they re-execute themselves with the project's
numeric profile before any library loads (:mod:`colcommon.numeric_env`); every worker and SITL
process they start inherits it. Flying, the console and the rest keep the CPU's own kernels.
"""

from __future__ import annotations

import sys

from colcommon.numeric_env import OPT_OUT, PROFILE, ensure_pinned

PINNED_COMMANDS = frozenset({"experiment", "eval", "ppo", "finetune"})


def command_of(argv: list[str]) -> str | None:
    """The subcommand named in ``argv`` (``col [--opt] NAME ...``), or None."""
    return next((a for a in argv[1:] if not a.startswith("-")), None)


def main() -> None:
    if command_of(sys.argv) in PINNED_COMMANDS:
        reason = ensure_pinned(sys.argv)  # returns only if already pinned, or if it cannot be
        if reason is not None:
            print(f"col: numeric profile {PROFILE} not applied ({reason}); "
                  f"unset {OPT_OUT} on an x86-64 CPU with AVX2 to apply it", file=sys.stderr)
    from companion.cli import app

    app()
