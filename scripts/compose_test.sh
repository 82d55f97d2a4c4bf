#!/usr/bin/env bash
# Build the images and test the compose stack end to end on this machine (service/README.md,
# "Deployment"): API, two CPU workers, PostgreSQL, Redis and SeaweedFS from docker/compose.yaml;
# a job through the API with the project's client, then a worker killed during reconstruction,
# Redis and PostgreSQL restarted during a job, the API restarted while clients follow a job
# (scripts/compose_e2e.py). Starts a Docker daemon if none runs (and stops only what it
# started), tears the stack down, and exits non-zero naming the failing step, with the
# containers' logs.
#
#   bash scripts/compose_test.sh
#   bash scripts/compose_test.sh --build-only           # daemon and images only (CI, meanwhile)
#   DCSEG_COMPOSE_KEEP=1 bash scripts/compose_test.sh   # leave the stack up afterwards
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
build_only=""
case "${1:-}" in
    "") ;;
    --build-only) build_only=1 ;;
    *) echo "usage: bash scripts/compose_test.sh [--build-only]" >&2; exit 2 ;;
esac

project="${DCSEG_COMPOSE_PROJECT:-dcsegtest}"
work="$(mktemp -d)"
step="set-up"
daemon_pid=""
compose=()
begin=$SECONDS

say() { echo "compose-test: $*" >&2; }
at() {
    step="$1"
    say "$step ($((SECONDS - begin)) s)"
}

teardown() {
    local rc=$?
    trap - EXIT
    if [ "$rc" -ne 0 ]; then
        say "FAILED at step '$step' (exit $rc)"
        if [ ${#compose[@]} -gt 0 ]; then
            "${compose[@]}" ps >&2 || true
            "${compose[@]}" logs --no-color --tail 150 >&2 || true
        fi
        [ -f "$work/dockerd.log" ] && tail -n 30 "$work/dockerd.log" >&2
    fi
    if [ ${#compose[@]} -gt 0 ] && [ -z "${DCSEG_COMPOSE_KEEP:-}" ]; then
        "${compose[@]}" down -v --remove-orphans >/dev/null 2>&1 || true
    fi
    if [ -n "$daemon_pid" ] && [ -z "${DCSEG_COMPOSE_KEEP:-}" ]; then
        kill "$daemon_pid" 2>/dev/null && wait "$daemon_pid" 2>/dev/null || true
    fi
    rm -rf "$work"
    say "done in $((SECONDS - begin)) s, exit $rc"
    exit "$rc"
}
trap teardown EXIT

need() {  # need COMMAND DEBIAN-PACKAGE...: install the packages when the command is missing
    local cmd="$1"
    shift
    command -v "$cmd" >/dev/null && return 0
    say "installing $* (apt)"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q "$@" >"$work/apt.log" 2>&1 \
        || { tail -n 20 "$work/apt.log" >&2; return 1; }
}

at "docker daemon"
need docker docker.io
need debootstrap debootstrap
if ! docker info >/dev/null 2>&1; then
    need dockerd docker.io
    dockerd >"$work/dockerd.log" 2>&1 &
    daemon_pid=$!
    for _ in $(seq 60); do docker info >/dev/null 2>&1 && break; sleep 0.5; done
    docker info >/dev/null 2>&1 || { say "dockerd did not start"; exit 1; }
    say "started dockerd (pid $daemon_pid)"
fi
if docker compose version >/dev/null 2>&1; then
    compose_cmd=(docker compose)
else
    need docker-compose docker-compose
    compose_cmd=(docker-compose)
fi

at "build images"
bash docker/build.sh
if [ -n "$build_only" ]; then
    step="tear down"
    exit 0
fi

at "start the stack"
python="python3"
[ -x .venv/bin/python ] && python=".venv/bin/python"
port() { "$python" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
key="compose-test:$(openssl rand -hex 16)"
export DCSEG_API_KEYS="$key" DCSEG_API_PORT="$(port)" DCSEG_S3_PORT="$(port)" \
    DCSEG_S3_SECRET_ACCESS_KEY="$(openssl rand -hex 16)" POSTGRES_PASSWORD="$(openssl rand -hex 16)"
export DCSEG_S3_PUBLIC_ENDPOINT_URL="http://127.0.0.1:$DCSEG_S3_PORT"
# a lost worker's job is picked up within 3 x heartbeat + this sweep interval (default 30 s)
cat >"$work/override.yaml" <<'YAML'
services:
  api:
    environment:
      DCSEG_SWEEP_INTERVAL_S: "5"
YAML
compose=("${compose_cmd[@]}" -p "$project" -f docker/compose.yaml -f "$work/override.yaml")
"${compose[@]}" down -v --remove-orphans >/dev/null 2>&1 || true  # a previous run's leftovers
"${compose[@]}" up -d --no-build --scale worker=2
api="http://127.0.0.1:$DCSEG_API_PORT"
for _ in $(seq 180); do
    curl -sf "$api/readyz" >/dev/null 2>&1 && break
    sleep 1
done
curl -sf "$api/readyz" >/dev/null || { say "the API at $api is not ready after 180 s"; exit 1; }

at "jobs and faults"
"$python" scripts/compose_e2e.py --api "$api" --key "${key#*:}" \
    --compose "${compose[*]}" --work "$work"
step="tear down"
