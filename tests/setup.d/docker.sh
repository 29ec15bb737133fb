#!/usr/bin/env bash
# The images of the Docker engine tests (tests/test_docker.py, marker `docker`), built without a registry:
# docker/offline.sh makes the local base images and the wheelhouse (debootstrap, installed if missing; the zenohd
# of tests/setup.d/zenohd.sh, built if missing; pip download of the locks), then compose builds the dronesim image
# from them.
# Idempotent and quick when nothing changed (labels keyed on the inputs, Docker's layer cache).
#
# It never fails the run: it writes what happened to $STATUS_FILE, which the engine tests read.
#   OK: ...         the images are built
#   NO ENGINE: ...  no Docker engine is reachable here: the engine tests skip with this reason
#   FAILED: ...     an engine is there but the images could not be built: the engine tests fail with it
# The engine tests run this script themselves too (quick), so they always use the tree's own image: with
# DRONESIM_IMAGE set (compose's variable), that is the image's tag.
set -uo pipefail
cd "$(dirname "$0")/../.."
STATUS_DIR="${XDG_CACHE_HOME:-$HOME/.cache}/dronesim"
STATUS_FILE="$STATUS_DIR/docker-setup.txt"
LOG_FILE="$STATUS_DIR/docker-setup.log"
mkdir -p "$STATUS_DIR"
status() { printf '%s\n' "$*" >"$STATUS_FILE"; echo "docker: $*"; }

if ! command -v docker >/dev/null 2>&1; then
  status "NO ENGINE: the docker command is not installed"
  exit 0
fi
if ! err="$(docker version --format '{{.Server.Version}}' 2>&1 >/dev/null)"; then
  status "NO ENGINE: no Docker engine reachable ($(echo "$err" | tail -n1))"
  exit 0
fi
if docker compose version >/dev/null 2>&1; then compose=(docker compose); else compose=(docker-compose); fi
if ! "${compose[@]}" version >/dev/null 2>&1; then
  status "FAILED: neither docker compose (v2) nor docker-compose (v1) is installed"
  exit 0
fi

start=$(date +%s)
if ! bash docker/offline.sh >"$LOG_FILE" 2>&1; then
  status "FAILED: docker/offline.sh: $(tail -n 3 "$LOG_FILE" | tr '\n' ' ')"
  exit 0
fi
# The dronesim image, as `up --build` builds it: one service builds the image all of them run.
# (Compose v1's client gives up on a silent daemon after COMPOSE_HTTP_TIMEOUT, 60 s by default; once, on a
# loaded machine, the client dropped a build midway with no error but a broken pipe in the daemon's log. One
# retry: a dropped build resumes from Docker's layer cache.)
export COMPOSE_HTTP_TIMEOUT="${COMPOSE_HTTP_TIMEOUT:-600}"
build() { "${compose[@]}" --env-file "$PWD/docker/offline.env" -f docker/compose.yaml build coordinator >>"$LOG_FILE" 2>&1; }
if ! build && ! { echo "(retrying the build once)" >>"$LOG_FILE"; build; }; then
  status "FAILED: ${compose[*]} build: $(tail -n 3 "$LOG_FILE" | tr '\n' ' ')"
  exit 0
fi
status "OK: $(grep -v '^#' docker/offline.env | xargs), ${DRONESIM_IMAGE:-dronesim:0.1.0} built by ${compose[*]} in $(( $(date +%s) - start ))s"
exit 0
