"""What the console's tests share: a console served in the test's own process."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from companion.config import CompanionConfig
from companion.console.server import ConsoleServer
from companion.console.session import ConsoleOptions, ConsoleSession
from tests.console.test_console_pages import Served


@pytest.fixture
def served(tmp_path: Path) -> Iterator[Served]:
    """A console with the default config on a free loopback port, its run folder in tmp_path."""
    cfg = CompanionConfig()
    s = Served(ConsoleServer(lambda publish, frame: ConsoleSession(cfg, ConsoleOptions(run_dir=tmp_path / "run"),
                                                                   publish, frame)))
    try:
        yield s
    finally:
        s.close()
