#!/usr/bin/env python3
"""The dronesim image's entrypoint (installed as /usr/local/bin/dronesim-entrypoint).

    dronesim-entrypoint dronesim coordinator --connect tcp/router:7447 ...     # run as given (exec)
    dronesim-entrypoint dronesim drone --id auto --connect tcp/router:7447 ... # claim the first free Dnn
    dronesim-entrypoint bash                                                  # anything else: exec'd

For an entity role (coordinator, env, drone, gcs) and for `dronesim router`, it first writes which entity this container
runs, and with which Zenoh flags, to $DRONESIM_STATE (a small JSON file), for the health check (docker/healthcheck.py).

``--id auto`` (docs/docker.md) tries D01, D02, ... in turn, running `dronesim drone --id Dnn` for each,
until the coordinator admits one: a taken id is refused ("D01 is already connected", "drone D01 is
already taken by H01"); "unknown drone Dnn", or no credentials for Dnn (its --password-file, --tls-cert or
--tls-key missing), means every drone of the game already flies (exit 2). A refused attempt leaves no
trace: presence tokens are per Zenoh session. ``{id}`` in any argument becomes
the entity id (SRV, ENV, GCS, the claimed Dnn, or Hnn): ``--tls-cert /certs/{id}.pem``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

#: dronesim subcommand -> the entity id it runs as (None: read from --id/--host, or a router).
ROLES = {"coordinator": "SRV", "env": "ENV", "gcs": "GCS", "drone": None, "router": None}
#: refusals that mean "this id is someone else's: try the next one".
TAKEN = re.compile(r"connection refused: .*(is already connected|is already taken)")
#: the refusal that means "there is no such drone in this game": every id is taken.
UNKNOWN = re.compile(r"connection refused: (unknown drone .*)")
MAX_ID = 65535
#: The flags naming a file of the process's own credentials: for `--id auto`, an id whose file is missing is one the
#: game has no credentials for (docker/compose.yaml makes them for its DRONES drones).
CREDENTIALS = ("--password-file", "--tls-cert", "--tls-key")


def flags(argv: list[str]) -> argparse.Namespace:
    """The flags that tell which entity a drone process runs as; the rest is dronesim's business."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--id")
    p.add_argument("--host")
    return p.parse_known_args(argv)[0]


def drone_entity(args: argparse.Namespace) -> str | None:
    """The entity a `dronesim drone` process connects as: its swarm host, or its one drone."""
    if args.host:
        return args.host
    ident = args.id or "D01"
    if ident.isdigit():
        return f"D{int(ident):02d}"
    return ident if re.fullmatch(r"D\d{2,5}", ident) else None


def missing_credentials(argv: list[str]) -> str | None:
    """The first file of the process's own credentials (`CREDENTIALS`) that `argv` names and that does not exist."""
    p = argparse.ArgumentParser(add_help=False)
    for flag in CREDENTIALS:
        p.add_argument(flag)
    args = vars(p.parse_known_args(argv)[0])
    return next((path for path in args.values() if path and not os.path.exists(path)), None)


def write_state(role: str, entity: str | None, argv: list[str]) -> None:
    path = Path(os.environ.get("DRONESIM_STATE", "/tmp/dronesim-entity.json"))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps({"role": role, "entity": entity, "argv": argv, "pid": os.getpid()}))
    tmp.replace(path)


def with_id(argv: list[str], ident: str) -> list[str]:
    """`argv` with its --id value replaced (it parsed: a value never starts with "--")."""
    out = list(argv)
    for i, arg in enumerate(argv):
        if arg == "--id" and i + 1 < len(argv):
            out[i + 1] = ident
        elif arg.startswith("--id="):
            out[i] = f"--id={ident}"
    return out


def fill(argv: list[str], entity: str | None) -> list[str]:
    """`{id}` in any argument becomes the entity id (e.g. --tls-cert /certs/{id}.pem)."""
    return [a.replace("{id}", entity) for a in argv] if entity else list(argv)


def dronesim(*args: str) -> list[str]:
    return [sys.executable, "-m", "dronesim", *args]


def exit_status(returncode: int) -> int:
    """The status this process passes on for its child's `returncode`: a child killed by signal N (-N) as shells and
    Docker report it, 128 + N (SIGTERM: 143); `sys.exit(-15)` would say 241."""
    return 128 - returncode if returncode < 0 else returncode


def claim(argv: list[str]) -> int:
    """Fly the first drone id the coordinator admits (see the module's doc); the drone's exit code."""
    proc: subprocess.Popen | None = None
    stopping, code = False, 0

    def forward(signum: int, _frame: object) -> None:  # docker stop: pass it on, try no further id
        nonlocal stopping
        stopping = True  # (the handler runs on this thread, between two steps of the loop below)
        if proc is not None and proc.poll() is None:
            proc.send_signal(signum)

    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, forward)
    for n in range(1, MAX_ID + 1):
        ident = f"D{n:02d}"
        args = fill(with_id(argv, ident), ident)
        write_state("drone", ident, args)
        if stopping:  # stopped between two attempts: start no other
            return code
        if missing := missing_credentials(args):  # (no use asking the coordinator: the router would not let it in)
            if n == 1:
                print(f"dronesim-entrypoint: no credentials for {ident}: {missing} is missing", file=sys.stderr,
                      flush=True)
            else:
                print(f"dronesim-entrypoint: no free drone id (no credentials for {ident}: {missing}): this replica is "
                      "one too many; start as many drone replicas as the coordinator's --drones (DRONES)",
                      file=sys.stderr, flush=True)
            return 2
        proc = subprocess.Popen(dronesim("drone", *args), stderr=subprocess.PIPE, text=True, bufsize=1)
        refusal = ""
        for line in proc.stderr:  # passed through, and scanned for a refusal (held back: it may be expected)
            if "connection refused:" in line and not refusal:
                refusal = line.strip()
                continue
            sys.stderr.write(line)
            sys.stderr.flush()
        code = exit_status(proc.wait())
        if refusal and (code == 0 or stopping or not TAKEN.search(refusal)):
            print(refusal, file=sys.stderr, flush=True)  # (a taken id is expected: the line below says it)
        if code == 0 or stopping or not refusal:
            return code
        if TAKEN.search(refusal):
            print(f"dronesim-entrypoint: {ident} is taken, trying the next id", file=sys.stderr, flush=True)
            continue
        if unknown := UNKNOWN.search(refusal):
            print(f"dronesim-entrypoint: no free drone id ({unknown.group(1)}): this replica is one too many; "
                  "start as many drone replicas as the coordinator's --drones (DRONES)", file=sys.stderr, flush=True)
        return code
    return 2


def main(argv: list[str]) -> int:
    argv = argv or ["dronesim", "--help"]
    if argv[0] != "dronesim":
        os.execvp(argv[0], argv)
    if len(argv) < 2 or argv[1] not in ROLES:  # --help, replay, bench, up: no entity to watch
        os.execv(sys.executable, dronesim(*argv[1:]))
    role, rest = argv[1], argv[2:]
    args = flags(rest)
    if role == "drone" and args.id == "auto":
        if args.host:
            print("dronesim-entrypoint: --id auto flies one drone: it takes no --host", file=sys.stderr)
            return 2
        return claim(rest)
    entity = ROLES[role] or (drone_entity(args) if role == "drone" else None)
    rest = fill(rest, entity)
    write_state(role, entity, rest)
    os.execv(sys.executable, dronesim(role, *rest))  # this process becomes the entity: same pid
    return 127  # not reached


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
