#!/usr/bin/env python3
"""The dronesim image's HEALTHCHECK (installed as /usr/local/bin/dronesim-health; docs/docker.md).

Healthy: this container's entity is *present on the network* and its game *makes progress*. Its liveliness token
``<root>/<ENTITY>/ALIVE/<session>``, which the coordinator watches, is asked of the router by a short-lived client
session with the entity's own Zenoh flags (--connect, --config: TLS and credentials included). Its progress is what
the process last noted in $DRONESIM_PROGRESS (network/progress.py): a step that stands still longer than
$DRONESIM_HEALTH_STALL seconds (default 60, schema/tuning.py) where it should not is unhealthy -- an entity not admitted, a game that
waits for entities that do not come (the coordinator's, new or resumed), a drones' phase that never ends -- and so is
an entity whose coordinator has vanished or that was refused. The ground station's phase may last (a person decides:
the page holds the game for its next target), and after the game's end the process is healthy while it lives (a
web ground station: while its page answers). For `dronesim router`, healthy means it accepts a Zenoh session on its
listen endpoint; a container running anything else (replay, bench, a shell) has nothing to check. The entrypoint
(docker/entrypoint.py) records which entity the container runs in $DRONESIM_STATE. Exit status 0: healthy, 1: unhealthy.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from schema.tuning import HEALTH_STALL_S, HEALTH_TIMEOUT_S  # noqa: E402 (the image's packages: `sys.path` as run)

TIMEOUT_S = float(os.environ.get("DRONESIM_HEALTH_TIMEOUT", HEALTH_TIMEOUT_S))
STALL_S = float(os.environ.get("DRONESIM_HEALTH_STALL", HEALTH_STALL_S))
#: Steps that may stand still without end: the ground station's phase (a person decides), and an entity admitted or
#: playing (the game's pace is the coordinator's and the ground station's: their own checks judge it; a drone hears
#: nothing before its first phase, which waits for the person). The end is apart.
STILL = {"GCS", "admitted", "playing"}
#: Steps that are unhealthy at once: the coordinator that admitted the entity has vanished, or it was refused.
WRONG = {"waiting", "refused"}


def probe_config(args: argparse.Namespace, connect: list[str]):
    """A client config reaching `connect`, with the entity's config file (TLS, credentials) if any."""
    from network.transport import zenoh_config

    conf = zenoh_config(argparse.Namespace(**{**vars(args), "mode": "client", "connect": connect, "listen": []}))
    conf.insert_json5("listen/endpoints", "[]")  # never take the entity's port
    return conf


def check(state: dict) -> tuple[bool, str]:
    import zenoh

    from network.transport import add_zenoh_args

    pid = state.get("pid")
    if pid and Path("/proc").is_dir() and not Path(f"/proc/{pid}").exists():
        return False, f"process {pid} is gone"
    parser = argparse.ArgumentParser(add_help=False)
    add_zenoh_args(parser)  # the entity's Zenoh flags, parsed by dronesim's own flag definitions
    args = parser.parse_known_args(list(state.get("argv", [])))[0]
    role, entity = state.get("role"), state.get("entity")
    if role == "router":
        # its listen endpoints as seen from inside the container (tcp/0.0.0.0:7447 -> tcp/127.0.0.1:7447)
        endpoints = [e.replace("0.0.0.0", "127.0.0.1").replace("[::]", "[::1]") for e in args.listen]
        endpoints = endpoints or ["tcp/127.0.0.1:7447"]
        try:
            with zenoh.open(probe_config(args, endpoints)):
                return True, f"router accepts sessions on {', '.join(endpoints)}"
        except Exception as exc:  # zenoh raises a bare ZError
            return False, f"router does not accept sessions on {', '.join(endpoints)}: {exc}"
    if not entity:
        return False, f"cannot tell which entity this {role} runs as (see its --id/--host)"
    from network.progress import PROGRESS_ENV, read_progress

    step = read_progress(os.environ[PROGRESS_ENV]) if os.environ.get(PROGRESS_ENV) else None
    page = web_page(state) if (step or {}).get("stage") != "connecting" else None  # (served once admitted)
    if page is not None and not page[0]:
        return page
    if step is not None and step.get("stage") in ("over", "OVER"):
        return True, f"{entity}: the game is over (turn {step.get('turn')}){'; ' + page[1] if page else ''}"
    from schema import Keys

    conf = probe_config(args, list(args.connect))
    endpoints = json.loads(conf.get_json("connect/endpoints"))  # --connect, or the entity's config file
    if isinstance(endpoints, dict):  # per-mode endpoints
        endpoints = endpoints.get("client", [])
    endpoints = [str(e) for e in endpoints or []]
    if not endpoints:
        return True, f"{entity}: no connect endpoint, nothing to check through"
    key = Keys(args.root).alive_of(entity)
    try:
        with zenoh.open(conf) as session:
            replies = list(session.liveliness().get(key, timeout=TIMEOUT_S))
    except Exception as exc:
        return False, f"{entity}: cannot reach the router at {', '.join(endpoints)}: {exc}"
    tokens = [str(r.ok.key_expr) for r in replies if r.ok is not None]
    if not tokens:
        return False, f"{entity}: no presence token {key} within {TIMEOUT_S:g} s (its session is down or not routed)"
    present = f"{entity} present: {', '.join(tokens)}"
    return (True, present) if step is None else progress(entity, step, present)


def progress(entity: str, step: dict, present: str) -> tuple[bool, str]:
    """Whether the step the entity last noted (network/progress.py) is progress; and what it is."""
    stage, turn, waiting = step.get("stage"), step.get("turn"), step.get("waiting") or ""
    age = max(0.0, time.time() - float(step.get("since", time.time())))
    where = f"{stage} at turn {turn} for {age:.0f} s" + (f", waiting for {waiting}" if waiting else "")
    if stage in WRONG:
        return False, f"{entity}: {where}"
    if stage not in STILL and age > STALL_S:
        return False, f"{entity}: no progress: {where} (more than {STALL_S:g} s)"
    return True, f"{present}; {where}"


def web_page(state: dict) -> tuple[bool, str] | None:
    """For a web ground station on a known port: whether its page answers (None: no page to check)."""
    import urllib.error
    import urllib.request

    if state.get("role") != "gcs":
        return None
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--web")
    web = parser.parse_known_args(list(state.get("argv", [])))[0].web
    host, _, port = (web or "").rpartition(":")
    if not port.isdigit() or int(port) == 0:
        return None
    host = {"": "127.0.0.1", "0.0.0.0": "127.0.0.1", "[::]": "[::1]"}.get(host, host)
    url = f"http://{host}:{port}/api/state"
    try:
        with urllib.request.urlopen(url, timeout=TIMEOUT_S) as reply:
            reply.read()
    except (OSError, urllib.error.URLError) as exc:
        return False, f"the page does not answer on {url}: {exc}"
    return True, f"the page answers on {url}"


def main() -> int:
    path = Path(os.environ.get("DRONESIM_STATE", "/tmp/dronesim-entity.json"))
    try:
        state = json.loads(path.read_text())
    except FileNotFoundError:
        print(f"healthy: no dronesim entity in this container ({path} absent)")
        return 0
    except (OSError, ValueError) as exc:
        print(f"unhealthy: unreadable {path}: {exc}")
        return 1
    ok, why = check(state)
    print(f"{'healthy' if ok else 'unhealthy'}: {why}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
