#!/usr/bin/env bash
# `make image-check`: build the runtime image with podman, run it, fly the compose session, report
# the image's size. For machines without a Docker engine or an image registry (docs/runtime.md):
#   - base image: a `debootstrap --variant=minbase bookworm` root filesystem from the Debian
#     mirror apt uses, slimmed (apt caches and lists, docs, man pages, locales) and imported
#     with `podman import` (once; kept as $BASE_IMAGE);
#   - podman with runc, cgroupfs and bounded ulimits (docker/containers.conf);
#   - the host's CA bundle is given to the build as a secret when the host has extra CA
#     certificates (TLS inspection), never copied into the image;
#   - docker-compose (v1) talks to `podman system service` over a socket (DOCKER_HOST).
# Needs root and the Debian packages podman, debootstrap, runc, docker-compose.
# Prints one JSON object as its last line (also written to $WORK/image-check.json).
set -euo pipefail
cd "$(dirname "$0")/.."

WORK=${COL_IMAGE_WORK:-/var/tmp/col-image}
BASE_IMAGE=${BASE_IMAGE:-localhost/debian-bookworm-minbase:latest}
IMAGE=${COL_IMAGE:-localhost/cycle-of-learning:runtime}
EPISODES=${COL_EPISODES:-2}
export CONTAINERS_CONF="$PWD/docker/containers.conf"
mkdir -p "$WORK"

say() { echo "== $*" >&2; }
fail() { echo "image-check: $*" >&2; exit 1; }

for tool in podman debootstrap runc docker-compose; do
    command -v "$tool" >/dev/null || fail "needs $tool: apt-get install -y podman debootstrap runc docker-compose"
done

debian_mirror() {  # the mirror apt is configured with (deb822 or one-line sources)
    local uri
    uri=$(grep -hsE '^URIs:' /etc/apt/sources.list.d/*.sources | awk '{print $2}' | grep -v security | head -n1 || true)
    [ -n "$uri" ] || uri=$(grep -hsE '^deb ' /etc/apt/sources.list /etc/apt/sources.list.d/*.list | awk '{print $2}' | grep -v security | head -n1 || true)
    echo "${uri:-http://deb.debian.org/debian}"
}

if ! podman image exists "$BASE_IMAGE"; then
    mirror=$(debian_mirror)
    say "base image $BASE_IMAGE: debootstrap --variant=minbase bookworm from $mirror"
    rm -rf "$WORK/rootfs"
    debootstrap --variant=minbase bookworm "$WORK/rootfs" "$mirror" >"$WORK/debootstrap.log" 2>&1 \
        || fail "debootstrap failed; see $WORK/debootstrap.log"
    rm -rf "$WORK"/rootfs/var/cache/apt/* "$WORK"/rootfs/var/lib/apt/lists/* \
        "$WORK"/rootfs/usr/share/doc/* "$WORK"/rootfs/usr/share/man/* "$WORK"/rootfs/usr/share/locale/*
    tar -C "$WORK/rootfs" -c . | podman import - "$BASE_IMAGE" >/dev/null
    rm -rf "$WORK/rootfs"
fi

ca_bundle="$WORK/ca-bundle.pem"  # the build secret: the host's bundle, or empty
: >"$ca_bundle"
if compgen -G "/usr/local/share/ca-certificates/*.crt" >/dev/null && [ -s /etc/ssl/certs/ca-certificates.crt ]; then
    cp /etc/ssl/certs/ca-certificates.crt "$ca_bundle"
fi

say "build $IMAGE (target runtime, FROM $BASE_IMAGE)"
podman build --network host --target runtime --build-arg "BASE_IMAGE=$BASE_IMAGE" \
    --secret "id=ca_bundle,src=$ca_bundle" -t "$IMAGE" . >"$WORK/build.log" 2>&1 \
    || { tail -n 30 "$WORK/build.log" >&2; fail "podman build failed; see $WORK/build.log"; }

say "run: col-sitl --help"
podman run --rm --network host "$IMAGE" col-sitl --help >/dev/null
say "run: the runtime image holds no torch, no compiler, no tests and runs as col"
podman run --rm --network host "$IMAGE" sh -c '
    [ "$(id -un)" = col ] || { echo "runs as $(id -un)"; exit 1; }
    for c in gcc cc g++ c++ make; do ! command -v $c >/dev/null || { echo "has $c"; exit 1; }; done
    ! python3 -c "import torch" 2>/dev/null || { echo "has torch"; exit 1; }
    [ ! -e /src ] && [ ! -e /home/col/tests ] || { echo "has sources or tests"; exit 1; }'

say "compose: the SITL and the companion flying $EPISODES episodes (podman system service)"
socket="$WORK/podman.sock"
rm -f "$socket"
podman system service --time=0 "unix://$socket" >"$WORK/service.log" 2>&1 &
service_pid=$!
health_pid=""
cleanup() {
    # -v: the check's own run volume (colcheck_runs) goes too, so the next check starts afresh
    DOCKER_HOST="unix://$socket" COL_IMAGE="$IMAGE" docker-compose -p colcheck down -v >/dev/null 2>&1 || true
    [ -z "$health_pid" ] || kill "$health_pid" 2>/dev/null || true
    kill "$service_pid" 2>/dev/null || true
}
trap cleanup EXIT
for _ in $(seq 50); do [ -S "$socket" ] && break; sleep 0.2; done
[ -S "$socket" ] || fail "podman system service did not open $socket; see $WORK/service.log"
# podman runs health checks from systemd timers; without systemd, run them here every 2 s
(while true; do
    for c in $(podman ps -q --filter label=com.docker.compose.project=colcheck); do
        podman healthcheck run "$c" >/dev/null 2>&1 || true
    done
    sleep 2
done) &
health_pid=$!
export DOCKER_HOST="unix://$socket" COL_IMAGE="$IMAGE" COL_EPISODES="$EPISODES"
docker-compose -p colcheck down -v >/dev/null 2>&1 || true  # a run volume an aborted check left
docker-compose -p colcheck up --no-build --abort-on-container-exit --exit-code-from companion \
    >"$WORK/compose.log" 2>&1 || { tail -n 40 "$WORK/compose.log" >&2; fail "compose session failed; see $WORK/compose.log"; }
summary=$(grep -o '{"episodes".*}' "$WORK/compose.log" | tail -n1 || true)
[ -n "$summary" ] || fail "the companion printed no summary; see $WORK/compose.log"

bytes=$(podman image inspect "$IMAGE" --format '{{.Size}}')
result=$(python3 -c 'import json, sys; print(json.dumps({"image": sys.argv[1], "base_image": sys.argv[2],
    "runtime_image_mb": round(int(sys.argv[3]) / 1e6, 1), "sitl_help": "ok", "lean_checks": "ok",
    "compose_session": json.loads(sys.argv[4])}))' "$IMAGE" "$BASE_IMAGE" "$bytes" "$summary")
echo "$result" >"$WORK/image-check.json"
echo "$result"
