"""The images, read statically (building them is `make image-check`, too heavy for the suite):
the Dockerfile's stages, what the runtime stage holds and who it runs as, the compose services
and their health checks."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
COMPILERS = ("gcc", "g++", "clang", "build-essential", "make", "cmake", "python3-dev")


def stages() -> dict[str, list[str]]:
    """Stage name -> its instruction lines (continuations joined), in file order."""
    text = re.sub(r"\\\n", " ", (REPO / "Dockerfile").read_text())
    out: dict[str, list[str]] = {"": []}
    current = ""
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if m := re.match(r"FROM\s+\S+\s+AS\s+(\S+)", line, re.IGNORECASE):
            current = m.group(1)
            out[current] = []
        out[current].append(line)
    return out


def test_the_dockerfile_has_runtime_and_dev_targets_from_a_base_argument() -> None:
    s = stages()
    assert {"base", "build", "dev", "runtime"} <= set(s)
    assert list(s)[-1] == "runtime"  # a plain `docker build .` gives the lean image
    assert any(line.startswith("ARG BASE_IMAGE=") for line in s[""])
    assert s["base"][0].startswith("FROM ${BASE_IMAGE} AS base")
    assert all(lines[0].split()[1] == "base" for name, lines in s.items() if name in ("build", "dev", "runtime"))


def test_the_runtime_stage_is_lean_and_runs_as_a_user() -> None:
    runtime = stages()["runtime"]
    text = "\n".join(runtime)
    assert "apt-get install" not in text
    assert not re.search(r"^COPY\s+(tests|bench|docs)\b", text, re.MULTILINE)
    assert re.search(r"^COPY --from=build /opt/col /opt/col$", text, re.MULTILINE)
    users = [line.split()[1] for line in runtime if line.startswith("USER ")]
    assert users and users[-1] not in ("root", "0")
    base = "\n".join(stages()["base"])
    assert not any(re.search(rf"install[^\n]*\b{re.escape(c)}\b", base) for c in COMPILERS)
    build = "\n".join(stages()["build"])
    assert re.search(r"pip install --quiet /src\b(?!\[)", build)  # the lean install: no extras
    # a compiler only where a wheel is missing (arm64), and only in the build stage
    assert re.search(r'\[ "\$\{TARGETARCH:-amd64\}" = amd64 \] \|\| packages="\$packages g\+\+"', build)


def build_packages(tmp_path: Path, arch: str, *, venv: bool, headers: bool) -> list[str]:
    """What the build stage's first RUN would apt-get install, run in sh against a stand-in
    ``python3`` that has (or lacks) ensurepip and the C headers."""
    run = next(line for line in stages()["build"] if line.startswith("RUN packages="))
    script = run[len("RUN "):run.index("if [ -n")] + 'echo "$packages"'
    fake = tmp_path / "bin" / "python3"
    fake.parent.mkdir(parents=True)
    venv_rc, headers_rc = int(not venv), int(not headers)
    fake.write_text(f'#!/bin/sh\ncase "$*" in *ensurepip*) exit {venv_rc};; *Python.h*) exit {headers_rc};; esac\nexit 3\n')
    fake.chmod(0o755)
    env = {"PATH": f"{fake.parent}:/usr/bin:/bin", "TARGETARCH": arch}
    done = subprocess.run(["sh", "-c", script], env=env, capture_output=True, text=True, check=True)
    return done.stdout.split()


def test_arm64_builds_get_a_compiler_and_the_python_headers_jsbsim_needs(tmp_path: Path) -> None:
    """jsbsim is a source build on arm64: g++, and python3-dev where the Python (Debian's, as on
    `make image-check`'s base) lacks Python.h; amd64 installs nothing, python:* images no headers."""
    assert build_packages(tmp_path / "a", "amd64", venv=True, headers=False) == []
    assert build_packages(tmp_path / "b", "arm64", venv=False, headers=False) == ["python3-venv", "g++", "python3-dev"]
    assert build_packages(tmp_path / "c", "arm64", venv=True, headers=True) == ["g++"]
    runtime = "\n".join(stages()["runtime"] + stages()["base"])
    assert "python3-dev" not in runtime


def test_the_dev_stage_installs_with_make_setup() -> None:
    dev = "\n".join(stages()["dev"])
    assert "make setup" in dev and "COPY tests ./tests" in dev
    # make setup builds jsbsim from source on arm64 too: a compiler, and the headers where missing
    assert '[ "${TARGETARCH:-amd64}" = amd64 ] || apt-get install -y --no-install-recommends g++' in dev
    assert re.search(r"Python\.h'\)\)\)\"\s+\|\| apt-get install -y --no-install-recommends python3-dev", dev)


def test_ca_certificates_reach_the_build_only_as_a_secret() -> None:
    text = (REPO / "Dockerfile").read_text()
    assert "--mount=type=secret,id=ca_bundle" in text
    assert not re.search(r"^(COPY|ADD)\b.*\b(ca|cert)", text, re.MULTILINE | re.IGNORECASE)


def test_compose_runs_sitl_and_companion_with_health_checks() -> None:
    yaml = pytest.importorskip("yaml")
    compose = yaml.safe_load((REPO / "compose.yaml").read_text())
    services = compose["services"]
    assert set(services) == {"sitl", "companion"}
    for name, service in services.items():
        assert service["build"]["target"] == "runtime", name
        check = service["healthcheck"]["test"]
        assert check[0] == "CMD" and len(check) > 1, name
    assert services["companion"]["depends_on"]["sitl"]["condition"] == "service_healthy"
    assert "col-sitl" in services["sitl"]["command"]
    assert "--condition col" in services["companion"]["command"]


def test_compose_keeps_the_run_folder_in_a_volume() -> None:
    """`docker compose down` removes containers, not named volumes: the dataset and the
    checkpoints the companion writes to runs/compose outlive the session."""
    yaml = pytest.importorskip("yaml")
    compose = yaml.safe_load((REPO / "compose.yaml").read_text())
    mounts = compose["services"]["companion"]["volumes"]
    assert "runs:/home/col/runs" in mounts
    assert "runs" in compose["volumes"] and not (compose["volumes"]["runs"] or {}).get("external")
    assert "--run-dir runs/compose" in compose["services"]["companion"]["command"]
    assert re.search(r"^WORKDIR /home/col$", "\n".join(stages()["runtime"]), re.MULTILINE)


def test_image_check_is_a_make_target_that_ci_does_not_run() -> None:
    assert re.search(r"^image-check:\n\tbash docker/image-check.sh$", (REPO / "Makefile").read_text(), re.MULTILINE)
    assert "image-check" not in (REPO / ".ci" / "run").read_text()
    assert subprocess.run(["bash", "-n", str(REPO / "docker" / "image-check.sh")]).returncode == 0
