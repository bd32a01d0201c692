# The companion and the SITL in one image. The install step is the README's `make setup`,
# so the image and a developer's checkout are built the same way.
FROM python:3.11-slim

RUN apt-get update \
    && apt-get install -y --no-install-recommends make libgl1 libglib2.0-0 \
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

RUN make setup PYTHON=python3
ENV PATH="/app/.venv/bin:${PATH}" OMP_NUM_THREADS=1

# Default: the demo (SITL started inside). For a real vehicle:
#   docker run --network host IMAGE col fly --connect udpin:0.0.0.0:14540 --pilot manual --condition col
CMD ["col", "demo"]
