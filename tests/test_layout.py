"""The house rules of the layout: no import cycles, the SITL stands alone, every package says
what it owns. Read from the source with ``ast``, so lazy imports inside functions count too."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TOP_PACKAGES = ("companion", "sitl", "colcommon")


def _module_name(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for top in TOP_PACKAGES for p in (REPO / top).rglob("*.py")}


def _imports(tree: ast.AST, known: dict[str, Path]) -> set[str]:
    """Modules of ours that a module imports; ``from pkg import sub`` names the submodule."""
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            subs = {f"{node.module}.{a.name}" for a in node.names} & known.keys()
            found.update(subs if len(subs) == len(node.names) else subs | {node.module})
    return found & known.keys()


def import_graph() -> dict[str, set[str]]:
    known = _modules()
    return {name: _imports(ast.parse(path.read_text()), known) - {name} for name, path in known.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as a path (first == last), or None; depth-first with colours."""
    colour: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        colour[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if colour.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in colour and (cycle := visit(nxt)):
                return cycle
        colour[node] = 2
        stack.pop()
        return None

    for node in sorted(graph):
        if node not in colour and (cycle := visit(node)):
            return cycle
    return None


def test_find_cycle_sees_a_cycle_and_its_absence() -> None:
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_no_import_cycle_between_modules() -> None:
    graph = import_graph()
    assert len(graph) > 50  # the walk found the project
    assert find_cycle(graph) is None


def test_no_import_cycle_between_companion_packages() -> None:
    def package(module: str) -> str:
        return ".".join(module.split(".")[:2])

    graph: dict[str, set[str]] = {}
    for module, targets in import_graph().items():
        graph.setdefault(package(module), set()).update(package(t) for t in targets)
    graph = {k: v - {k} for k, v in graph.items()}
    assert find_cycle(graph) is None


@pytest.mark.parametrize(("top", "forbidden"), [("sitl", ("companion",)), ("colcommon", ("companion", "sitl"))])
def test_lower_layers_import_nothing_above_them(top: str, forbidden: tuple[str, ...]) -> None:
    bad = {m: sorted(t for t in targets if t.split(".")[0] in forbidden)
           for m, targets in import_graph().items() if m.split(".")[0] == top}
    assert {m: t for m, t in bad.items() if t} == {}


LAYERS: tuple[tuple[str, ...], ...] = (
    # top to bottom: a package imports only from the layers below its own (README's order)
    ("entry",),
    ("cli",),
    ("console",),
    ("experiment",),
    ("rl",),
    ("inprocess",),
    ("app",),
    ("pictures",),
    ("control", "testing"),
    ("inputs", "learning"),
    ("commands", "vision"),
    ("link", "shared_facts"),
    ("msg",),
    ("config", "run_folder", "simulator", "statistics"),
    ("errors",),
)
EPISODE_CORE = ("companion.control.outcome", "companion.control.setpoint_rows", "companion.control.arbiter",
                "companion.control.records", "companion.control.lanes", "companion.control.step",
                "companion.control.demo_noise")
"""The episode core: one rule for how an episode ends and is scored, one setpoint arithmetic,
the batched episode core on its vehicle port, one vehicle's step decision; the drivers (the session in
companion.control.session, the env, the batched env, the batched evaluation) sit above it."""


def _layer(module: str) -> int | None:
    parts = module.split(".")
    if parts[0] != "companion" or len(parts) == 1:
        return None  # the root package: below everything
    return next(i for i, layer in enumerate(LAYERS) if parts[1] in layer)


def test_every_companion_package_has_a_layer() -> None:
    packages = {m.split(".")[1] for m in import_graph() if m.startswith("companion.")}
    assert packages == {name for layer in LAYERS for name in layer}


def test_packages_import_only_from_the_layers_below_their_own() -> None:
    upward = sorted(f"{m} -> {t}" for m, targets in import_graph().items() for t in targets
                    if (mine := _layer(m)) is not None and (theirs := _layer(t)) is not None
                    and theirs <= mine and m.split(".")[1] != t.split(".")[1])
    assert upward == []


def test_the_episode_core_sits_below_every_driver() -> None:
    graph = import_graph()
    for core in EPISODE_CORE:
        reach, todo = set(), [core]
        while todo:
            for t in graph[todo.pop()] - reach:
                reach.add(t)
                todo.append(t)
        drivers = {"companion.control.session", "companion.rl.gym_env", "companion.rl.batched_env",
                   "companion.experiment.batched_eval", "companion.app", "companion.inprocess"}
        assert reach & drivers == set(), core


def test_every_package_says_what_it_owns() -> None:
    missing = [str(p.relative_to(REPO)) for top in TOP_PACKAGES for p in (REPO / top).rglob("__init__.py")
               if not ast.get_docstring(ast.parse(p.read_text()))]
    assert missing == []


def test_the_image_copies_every_package_it_installs() -> None:
    """The Dockerfile copies folders one by one; a package left out fails only at `docker build`."""
    dockerfile = (REPO / "Dockerfile").read_text()
    pyproject = (REPO / "pyproject.toml").read_text()
    for top in TOP_PACKAGES:
        assert f'"{top}*"' in pyproject
        assert f"COPY {top} ./{top}" in dockerfile


def test_the_readme_stays_short_and_its_links_resolve() -> None:
    """A newcomer's page (at most 8 KB; results live in docs/results.md): every relative link of
    it and of docs/*.md names a file that exists."""
    readme = REPO / "README.md"
    assert readme.stat().st_size <= 8 * 1024
    broken = []
    for page in [readme, *sorted((REPO / "docs").glob("*.md"))]:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text()):
            if "://" not in target and not target.startswith("mailto:") and not (page.parent / target).exists():
                broken.append(f"{page.relative_to(REPO)} -> {target}")
    assert broken == []


FLIGHT_RUNTIME = ("companion.link", "companion.vision.observer", "companion.vision.camera", "companion.control",
                  "companion.console.frames", "companion.inputs", "companion.learning", "companion.commands")
"""The companion's modules that fly: they share messages with the SITL through colcommon, and
import nothing of sitl (the rendered camera, the camera bridge, the console's RTP video, the
in-process SITL and the wiring may: they run our SITL's code on purpose)."""


def test_the_flight_runtime_imports_nothing_of_the_sitl() -> None:
    bad = sorted(f"{m} -> {t}" for m, targets in import_graph().items() if m.startswith(FLIGHT_RUNTIME)
                 for t in targets if t.split(".")[0] == "sitl")
    assert bad == []
