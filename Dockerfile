# Two images from one file (docs/runtime.md):
#   runtime (the default, last stage): the lean flight install - fly a checkpoint, run the SITL,
#            learn with the NumPy trainer; no torch, no compilers, no tests; runs as user `col`.
#   dev:     everything, installed by the README's `make setup` (torch, the experiment, tests).
#
#   docker build -t col:runtime .                    docker build --target dev -t col:dev .
#   docker buildx build --platform linux/amd64,linux/arm64 -t col:runtime .
#
# BASE_IMAGE: any Debian bookworm-like image; Python 3.10+ is installed from its packages when
# the image has none (a `debootstrap --variant=minbase bookworm` root filesystem works).
# Where the network inspects TLS, give pip the extra CA certificates at build time only:
#   docker build --secret id=ca_bundle,src=/path/to/ca-bundle.pem .
ARG BASE_IMAGE=python:3.11-slim-bookworm

FROM ${BASE_IMAGE} AS base
ENV DEBIAN_FRONTEND=noninteractive PYTHONDONTWRITEBYTECODE=1 PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1
# Python from the distribution when the base image has none; no compiler either way.
RUN if ! command -v python3 >/dev/null; then \
        apt-get update \
        && apt-get install -y --no-install-recommends python3 \
        && rm -rf /var/lib/apt/lists/* /var/cache/apt/*; \
    fi

# -- build: the lean install into a venv that the runtime stage copies whole ------------------
FROM base AS build
# jsbsim publishes no Linux wheel for arm64: there pip builds it from source (CMake comes from
# PyPI, the C++ compiler and, where the Python is Debian's, its headers `python3-dev` from here;
# the python:* images ship their headers). Only this stage has them; the runtime copies no tool.
ARG TARGETARCH
RUN packages=""; \
    python3 -c "import ensurepip" 2>/dev/null || packages="python3-venv"; \
    [ "${TARGETARCH:-amd64}" = amd64 ] || packages="$packages g++"; \
    [ "${TARGETARCH:-amd64}" = amd64 ] \
        || python3 -c "import os, sysconfig; raise SystemExit(not os.path.exists(os.path.join(sysconfig.get_path('include'), 'Python.h')))" \
        || packages="$packages python3-dev"; \
    if [ -n "$packages" ]; then \
        apt-get update \
        && apt-get install -y --no-install-recommends $packages \
        && rm -rf /var/lib/apt/lists/* /var/cache/apt/*; \
    fi
WORKDIR /src
COPY pyproject.toml README.md ./
COPY companion ./companion
COPY sitl ./sitl
COPY colcommon ./colcommon
RUN --mount=type=secret,id=ca_bundle \
    if [ -s /run/secrets/ca_bundle ]; then export PIP_CERT=/run/secrets/ca_bundle; fi \
    && python3 -m venv /opt/col \
    && /opt/col/bin/pip install --quiet /src \
    && /opt/col/bin/pip uninstall --quiet -y lxml setuptools pip \
    && cd /opt/col/lib/python3*/site-packages \
    && find . -name tests -path "./*/tests" -prune -exec rm -rf {} + \
    && find . -name "*.pyi" -delete && rm -rf numpy/distutils \
    && find pymavlink/dialects/v10 -type f ! -name "__init__*" ! -name "all.*" -delete \
    && find pymavlink/dialects/v20 -type f ! -name "__init__*" ! -name "all.*" ! -name "common.*" \
        ! -name "ardupilotmega.*" -delete
# Left out of the runtime: pymavlink's generated MAVLink dialects but the ones it loads (v10
# `all`, pymavlink's default; v20 `all`, `common`, `ardupilotmega`: about 30 MB), lxml (used
# only to generate dialects), test folders, type stubs and numpy.distutils (a build tool).

# -- dev: everything, the way a developer's checkout is installed --------------------------------
FROM base AS dev
# make setup builds jsbsim from source on arm64 as the build stage does: the same compiler and headers
ARG TARGETARCH
RUN apt-get update \
    && apt-get install -y --no-install-recommends make libgl1 libglib2.0-0 \
    && (python3 -c "import ensurepip" 2>/dev/null || apt-get install -y --no-install-recommends python3-venv) \
    && { [ "${TARGETARCH:-amd64}" = amd64 ] || apt-get install -y --no-install-recommends g++; } \
    && { [ "${TARGETARCH:-amd64}" = amd64 ] \
        || python3 -c "import os, sysconfig; raise SystemExit(not os.path.exists(os.path.join(sysconfig.get_path('include'), 'Python.h')))" \
        || apt-get install -y --no-install-recommends python3-dev; } \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /app
COPY pyproject.toml Makefile README.md ./
COPY companion ./companion
COPY sitl ./sitl
COPY colcommon ./colcommon
COPY configs ./configs
COPY bench ./bench
COPY tests ./tests
COPY docs ./docs
RUN --mount=type=secret,id=ca_bundle \
    if [ -s /run/secrets/ca_bundle ]; then export PIP_CERT=/run/secrets/ca_bundle; fi \
    && make setup PYTHON=python3
ENV PATH="/app/.venv/bin:${PATH}" OMP_NUM_THREADS=1
CMD ["col", "demo"]

# -- runtime: the lean flight image ------------------------------------------------------------
FROM base AS runtime
COPY --from=build /opt/col /opt/col
COPY configs /opt/col/configs
RUN echo "col:x:10001:10001:Cycle-of-Learning companion:/home/col:/usr/sbin/nologin" >> /etc/passwd \
    && echo "col:x:10001:" >> /etc/group \
    && mkdir -p /home/col/runs && chown -R 10001:10001 /home/col
USER col
WORKDIR /home/col
ENV PATH="/opt/col/bin:${PATH}" OMP_NUM_THREADS=1 PYTHONUNBUFFERED=1
# For a real vehicle (a checkpoint mounted at /home/col/policy.npz):
#   docker run --network host -v $PWD/policy.npz:/home/col/policy.npz:ro IMAGE \
#     col fly --connect udpin:0.0.0.0:14540 --checkpoint policy.npz --condition eval --pilot none
CMD ["col", "--help"]
