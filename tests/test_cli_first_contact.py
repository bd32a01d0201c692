"""The ``col`` command as a new user meets it: help that shows what it says, bad input refused
with a clear error before anything is written, and options that are not silently ignored."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from companion import cli

WIDE = {"COLUMNS": "1000", "TERMINAL_WIDTH": "1000", "NO_COLOR": "1"}
RICH_TAG = re.compile(r"\\?\[[a-z#/@][^\[\]]*\]")  # what Rich markup would take for a tag


def help_texts(command: typer.core.TyperCommand) -> list[str]:
    """The command's own help and every parameter's, as written in the source."""
    return [command.help or "", *(getattr(p, "help", None) or "" for p in command.params)]


def commands() -> dict[str, typer.core.TyperCommand]:
    group = typer.main.get_command(cli.app)
    return dict(group.commands)  # type: ignore[attr-defined]


@pytest.mark.parametrize("name", sorted(commands()))
def test_help_shows_bracketed_text_as_written(name: str) -> None:
    """``[batch, 15]`` or ``[companion.learner]`` must not vanish as Rich markup."""
    shown = CliRunner().invoke(cli.app, [name, "--help"], env=WIDE)
    assert shown.exit_code == 0, shown.output
    output = " ".join(shown.output.split())
    for text in help_texts(commands()[name]):
        for tag in RICH_TAG.findall(text):
            assert tag.lstrip("\\") in output, f"{name} --help lost {tag!r}"


def test_export_help_names_the_tensor_shapes() -> None:
    for args in (["--help"], ["export", "--help"]):
        shown = CliRunner().invoke(cli.app, args, env=WIDE)
        assert "[batch, 15]" in shown.output and "[batch, 4]" in shown.output, shown.output


def invoke(*args: str):  # type: ignore[no-untyped-def]
    return CliRunner().invoke(cli.app, list(args), env=WIDE)


def test_a_mistyped_pilot_or_connection_is_refused_and_leaves_no_run_folder(tmp_path: Path,
                                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # the default run folder, runs/<time>-demo, would be made here
    bob = invoke("fly", "--pilot", "bob", "--episodes", "1")
    assert bob.exit_code == 2 and "unknown pilot 'bob'" in bob.output
    bogus = invoke("fly", "--connect", "bogus://x", "--episodes", "1", "--run-dir", "r")
    assert bogus.exit_code == 2 and "unknown scheme 'bogus'" in bogus.output, bogus.output
    assert "int()" not in bogus.output and "dialout" not in bogus.output
    missing = invoke("eval", "nope.npz", "--episodes", "1")
    assert missing.exit_code == 2 and "nope.npz does not exist" in missing.output
    assert "save_checkpoint" not in missing.output and "col fly" in missing.output  # no internal names
    assert list(tmp_path.iterdir()) == []


@pytest.fixture
def no_grid(monkeypatch: pytest.MonkeyPatch) -> list[object]:
    """``run_grid`` and the report replaced: what the command would have run, and nothing run."""
    import companion.experiment.report as report
    import companion.experiment.runner as runner

    calls: list[object] = []

    def run_grid(setup, out_dir, workers, **kw):  # type: ignore[no-untyped-def]
        calls.append(setup)
        return []

    def write_report(results, out_dir: Path) -> Path:  # type: ignore[no-untyped-def]
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "report.md").write_text("report\n")
        return out_dir / "report.md"

    monkeypatch.setattr(runner, "run_grid", run_grid)
    monkeypatch.setattr(report, "write_report", write_report)
    return calls


@pytest.mark.parametrize("options", [["--seed", "0"], ["--trials", "5"], ["--trial", "P1-col-04-s0"], ["--keep", "kept"]])
def test_verify_only_options_without_verify_are_refused(tmp_path: Path, no_grid: list[object],
                                                        options: list[str]) -> None:
    """Silently ignored, they ran the whole grid instead of the few trials asked for."""
    done = invoke("experiment", "--quick", "--out", str(tmp_path / "out"), *options)
    assert done.exit_code == 2 and f"{options[0]} only apply with --verify" in done.output, done.output
    assert no_grid == [] and not (tmp_path / "out").exists()


def test_verify_keeps_its_reruns_only_in_a_new_or_empty_folder(tmp_path: Path) -> None:
    """Nothing of a folder that holds something is mixed with, or lost to, the reruns."""
    full = tmp_path / "full"
    full.mkdir()
    (full / "mine.txt").write_text("keep me")
    done = invoke("experiment", "--verify", "results/paper-grid", "--trial", "P1-col-04-s0", "--keep", str(full))
    assert done.exit_code == 2 and "give a new or empty folder" in done.output, done.output
    assert [p.name for p in full.iterdir()] == ["mine.txt"]


def test_an_unknown_backend_is_refused_before_anything_is_written(tmp_path: Path, no_grid: list[object]) -> None:
    done = invoke("experiment", "--quick", "--backend", "foo", "--out", str(tmp_path / "out"))
    assert done.exit_code == 2 and "unknown --backend 'foo'; use process or ray" in done.output, done.output
    address = invoke("experiment", "--quick", "--address", "h:1", "--out", str(tmp_path / "out"))
    assert address.exit_code == 2 and "--address is for --backend ray" in address.output
    assert no_grid == [] and not (tmp_path / "out").exists()


def test_experiment_quick_finds_its_preset_outside_the_repository(tmp_path: Path, no_grid: list[object],
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    done = invoke("experiment", "--quick", "--workers", "1")
    assert done.exit_code == 0, done.output
    (setup,) = no_grid
    assert setup.config_path == Path(cli.__file__).resolve().parents[1] / "configs" / "experiment_quick.toml"  # type: ignore[attr-defined]
    assert (tmp_path / "runs" / "experiment_quick").is_dir()  # results where the user is


def test_a_preset_found_nowhere_says_to_pass_a_config(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from companion.errors import ConfigError

    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match="--config FILE"):
        cli.find_config("no_such_preset.toml")
