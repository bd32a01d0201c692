# One entry point for people and CI. `make demo` and `make test` install first.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: setup setup-browser test test-all demo bench lint clean image-check constraints

setup: $(STAMP)

# The CPU build of torch goes in first so that the project's torch range is already met
# and pip never reaches for a multi-GB CUDA build.
# TORCH_INDEX: where pip finds the CPU build (empty: the configured index, which here holds it;
# on plain PyPI use TORCH_INDEX=https://download.pytorch.org/whl/cpu or pip takes a CUDA build).
# constraints.txt pins every package to the version committed results were made with.
TORCH_INDEX ?=
EXTRAS := train,mavsdk,gamepad,console,onnx,test,cluster

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet torch==2.13.0 $(if $(TORCH_INDEX),--index-url $(TORCH_INDEX) --extra-index-url https://pypi.org/simple)
	$(PY) -m pip install --quiet -c constraints.txt -e '.[$(EXTRAS)]'
	touch $(STAMP)

# Rewrite constraints.txt from what the venv holds (after a deliberate upgrade).
constraints: setup
	{ sed -n '1,2p' constraints.txt; $(PY) -m pip freeze --exclude-editable | grep -v '^#' | sed 's/+cpu$$//'; } > constraints.tmp && mv constraints.tmp constraints.txt

# Debian's chromium for the console's browser test (Playwright's own download is not needed)
setup-browser:
	command -v chromium >/dev/null 2>&1 || (apt-get update -q && apt-get install -y -q chromium)

# Four workers on two cores: much of the suite waits on real-time flights (real autopilots,
# real-time SITL, the console), so four at once overlap those waits with the CPU-bound tests:
# 9.1 minutes where two workers took 13.2 (bench/results/make-test-n4-2026-12-02.txt, -n2-).
TEST_WORKERS ?= 4
test: setup
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadgroup

test-all: setup
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadgroup -m ''

demo: setup
	$(VENV)/bin/col demo

bench: setup
	@for b in bench/*.py; do [ "$$b" = bench/ab.py ] && continue; echo "== $$b"; $(PY) $$b || exit 1; done

lint: setup
	$(PY) -m ruff check companion sitl colcommon tests bench
	$(PY) -m mypy companion sitl colcommon

# The lean runtime image built with podman, run, and flown with compose (docs/runtime.md).
# Needs root and Debian's podman, debootstrap, runc, docker-compose; takes minutes: not in CI.
image-check:
	bash docker/image-check.sh

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info
