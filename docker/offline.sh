#!/usr/bin/env bash
# Makes, with no container registry, what docker/compose.yaml builds from (docs/docker.md, "Offline"):
#
#   PYTHON_IMAGE  dronesim-local/python:3.11-bookworm  a Debian bookworm root with Python 3.11, made by
#                 debootstrap from Debian's packages and `docker import`ed (stands for python:3.11-slim)
#   ZENOH_IMAGE   dronesim-local/zenoh:<pin>           that root plus the zenohd that cargo builds
#                 (tests/setup.d/zenohd.sh, run here when ~/.cargo/bin/zenohd is missing: about 10 minutes
#                 once; stands for eclipse/zenoh:<pin>)
#   WHEELHOUSE    docker/wheelhouse                    the wheels of docker/*requirements.lock for the
#                 engine's architecture, checked against the locks' sha256
#
# and writes them to docker/offline.env, which compose reads with --env-file (Compose v1: docker-compose):
#
#   bash docker/offline.sh
#   docker compose --env-file docker/offline.env -f docker/compose.yaml up --build
#
# Each part is made once and kept while its inputs are unchanged (an image label holds the hash of its
# recipe; the wheelhouse a stamp of the locks): a second run takes a few seconds. From zero it needs root
# (debootstrap; it installs debootstrap with apt-get when missing), Debian's package mirror (DEBIAN_MIRROR),
# cargo and crates.io for zenohd (or ZENOHD=a zenohd <pin> binary), PyPI for the wheels.
set -euo pipefail
cd "$(dirname "$0")/.."

PIN="$(sed -n 's/.*"eclipse-zenoh==\([0-9.]*\)".*/\1/p' pyproject.toml | head -n1)"
SUITE=bookworm
MIRROR="${DEBIAN_MIRROR:-http://deb.debian.org/debian}"
PACKAGES=python3,python3-venv,python3-pip   # Python 3.11 in bookworm; venv and pip as python:3.11-slim has
PYTHON_IMAGE="${PYTHON_IMAGE:-dronesim-local/python:3.11-bookworm}"
ZENOH_IMAGE="${ZENOH_IMAGE:-dronesim-local/zenoh:$PIN}"
WHEELHOUSE="${WHEELHOUSE:-docker/wheelhouse}"
CARGO_ZENOHD="${CARGO_HOME:-$HOME/.cargo}/bin/zenohd"   # where tests/setup.d/zenohd.sh installs it
ZENOHD="${ZENOHD:-$CARGO_ZENOHD}"
ENV_FILE="${ENV_FILE:-docker/offline.env}"
LABEL=org.dronesim.inputs
WORK="${XDG_CACHE_HOME:-$HOME/.cache}/dronesim/offline"

say() { echo "offline: $*"; }
die() { echo "offline: $*" >&2; exit 1; }
hash_of() { sha256sum | cut -c1-32; }
label_of() { docker image inspect --format "{{ index .Config.Labels \"$LABEL\" }}" "$1" 2>/dev/null || true; }

docker version --format '{{.Server.Version}}' >/dev/null 2>&1 || die "no Docker engine reachable (docker version failed)"
[ -n "$PIN" ] || die "cannot read eclipse-zenoh's version from pyproject.toml"

# --------------------------------------------------------------------------- the Python base image
make_root() {  # make_root DIR: a minimal bookworm with Python 3.11, without apt's caches and docs
  debootstrap --variant=minbase --include="$PACKAGES" "$SUITE" "$1" "$MIRROR"
  chroot "$1" python3 -c 'import sys, venv, ensurepip; assert sys.version_info[:2] == (3, 11), sys.version'
  rm -rf "$1"/var/cache/apt/archives/*.deb "$1"/var/lib/apt/lists/* "$1"/usr/share/doc/* "$1"/usr/share/man/* \
         "$1"/usr/share/locale/* "$1"/var/log/*.log "$1"/tmp/* "$1"/root/.cache
  echo dronesim-local >"$1/etc/hostname"
}
base_key="$( { echo "$SUITE $MIRROR $PACKAGES"; declare -f make_root; } | hash_of)"
if [ "$(label_of "$PYTHON_IMAGE")" = "$base_key" ]; then
  say "$PYTHON_IMAGE is up to date"
else
  [ "$(id -u)" = 0 ] || die "debootstrap needs root"
  if ! command -v debootstrap >/dev/null && command -v apt-get >/dev/null; then
    say "installing debootstrap (apt-get)"
    export DEBIAN_FRONTEND=noninteractive
    { apt-get install -y -qq debootstrap || { apt-get update -qq && apt-get install -y -qq debootstrap; }; } >/dev/null 2>&1
  fi
  command -v debootstrap >/dev/null || die "debootstrap is missing and apt-get could not install it (apt-get install debootstrap)"
  say "making $PYTHON_IMAGE: debootstrap $SUITE from $MIRROR (a few minutes)"
  mkdir -p "$WORK"
  root="$(mktemp -d "$WORK/root.XXXXXX")"
  trap 'rm -rf "$root"' EXIT
  make_root "$root" >"$WORK/debootstrap.log" 2>&1 || { tail -n 20 "$WORK/debootstrap.log" >&2; die "debootstrap failed (log: $WORK/debootstrap.log)"; }
  tar -C "$root" --numeric-owner -c . | docker import \
      --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
      --change 'ENV LANG=C.UTF-8' \
      --change "LABEL $LABEL=$base_key" \
      --change 'CMD ["python3"]' \
      --message "debootstrap $SUITE $PACKAGES" - "$PYTHON_IMAGE" >/dev/null
  rm -rf "$root"
  trap - EXIT
  say "made $PYTHON_IMAGE ($(docker run --rm "$PYTHON_IMAGE" python3 --version))"
fi

# --------------------------------------------------------------------------- the router image
zenohd_is_pin() { [ -x "$ZENOHD" ] && "$ZENOHD" --version 2>/dev/null | grep -q "v$PIN\b"; }
if ! zenohd_is_pin && [ "$ZENOHD" = "$CARGO_ZENOHD" ]; then
  say "no zenohd $PIN at $ZENOHD: building it with cargo (tests/setup.d/zenohd.sh; about 10 minutes, once)"
  bash tests/setup.d/zenohd.sh >&2
fi
if ! zenohd_is_pin; then
  [ -x "$ZENOHD" ] || die "no zenohd at $ZENOHD: $(cat "${XDG_CACHE_HOME:-$HOME/.cache}/dronesim/zenohd-install.txt" 2>/dev/null || echo "give ZENOHD=a zenohd $PIN")"
  die "$ZENOHD is not zenohd $PIN: $("$ZENOHD" --version 2>&1 | head -n1)"
fi
router_key="$( { sha256sum <"$ZENOHD"; cat docker/zenohd.Dockerfile; docker image inspect --format '{{.Id}}' "$PYTHON_IMAGE"; } | hash_of)"
if [ "$(label_of "$ZENOH_IMAGE")" = "$router_key" ]; then
  say "$ZENOH_IMAGE is up to date"
else
  ctx="$(mktemp -d)"
  trap 'rm -rf "$ctx"' EXIT
  cp "$ZENOHD" "$ctx/zenohd"
  cp docker/zenohd.Dockerfile "$ctx/Dockerfile"
  DOCKER_BUILDKIT=0 docker build --quiet --build-arg "BASE_IMAGE=$PYTHON_IMAGE" --label "$LABEL=$router_key" \
    -t "$ZENOH_IMAGE" "$ctx" >/dev/null 2>"$ctx/build.log" || { cat "$ctx/build.log" >&2; die "building $ZENOH_IMAGE failed"; }
  rm -rf "$ctx"
  trap - EXIT
  say "made $ZENOH_IMAGE ($(docker run --rm "$ZENOH_IMAGE" --version 2>/dev/null | tail -n1))"
fi

# --------------------------------------------------------------------------- the wheelhouse
case "$(docker info --format '{{.Architecture}}')" in
  x86_64|amd64) arch=x86_64 ;;
  aarch64|arm64) arch=aarch64 ;;
  *) die "no locked wheels for the engine's architecture $(docker info --format '{{.Architecture}}')" ;;
esac
locks=(docker/requirements.lock docker/build-requirements.lock)
wheel_key="$( { echo "$arch"; cat "${locks[@]}"; } | hash_of)"
if [ "$(cat "$WHEELHOUSE/.inputs" 2>/dev/null)" = "$wheel_key" ]; then
  say "$WHEELHOUSE is up to date"
else
  say "downloading the locked wheels for $arch into $WHEELHOUSE"
  rm -f "$WHEELHOUSE"/*.whl "$WHEELHOUSE/.inputs"
  platforms=(--platform "manylinux2014_$arch"); for m in $(seq 36 -1 17); do platforms+=(--platform "manylinux_2_${m}_$arch"); done
  for lock in "${locks[@]}"; do  # --require-hashes: every wheel's sha256 must be the lock's
    python3 -m pip download --quiet --disable-pip-version-check --no-deps --only-binary=:all: --require-hashes \
      --python-version 3.11 --implementation cp --abi cp311 --abi abi3 --abi none "${platforms[@]}" --platform any \
      -d "$WHEELHOUSE" -r "$lock"
  done
  echo "$wheel_key" >"$WHEELHOUSE/.inputs"
  say "$WHEELHOUSE: $(cd "$WHEELHOUSE" && ls *.whl | xargs)"
fi

# the search's compiled library, built by this machine's C compiler into the wheelhouse: the image's runtime has none
# (docker/Dockerfile ships it if it loads there; without, the search runs in Python: the same games, slower turns)
PYTHONPATH=. python3 -m coordinator.compiled --build "$WHEELHOUSE" | sed 's/^/offline: /'

{
  echo "# Written by docker/offline.sh: the local base images and wheelhouse (docs/docker.md, Offline)."
  echo "PYTHON_IMAGE=$PYTHON_IMAGE"
  echo "ZENOH_IMAGE=$ZENOH_IMAGE"
  echo "WHEELHOUSE=$WHEELHOUSE"
} >"$ENV_FILE"
if docker compose version >/dev/null 2>&1; then compose="docker compose"; else compose=docker-compose; fi
say "wrote $ENV_FILE: $compose --env-file $ENV_FILE -f docker/compose.yaml up --build"
