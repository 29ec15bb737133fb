"""The ``dronesim`` command: one subcommand per process role, plus the tools."""

from __future__ import annotations

import importlib
import sys

#: subcommand -> (module, function taking argv, help line); the module is imported on use.
COMMANDS: dict[str, tuple[str, str, str]] = {
    "up": ("dronesim.up", "cli", "run everything on one machine (embedded router + every entity)"),
    "coordinator": ("dronesim.roles", "coordinator", "the coordinator (SRV + observer)"),
    "env": ("entities.env_node", "cli", "the environment (ENV)"),
    "drone": ("entities.drone_node", "cli", "a drone, or a swarm host of several drones"),
    "gcs": ("dronesim.roles", "gcs", "the ground control station (GCS)"),
    "ros2": ("entities.ros2.node", "cli", "the game as ROS 2 topics (rmw_zenoh) and live in Foxglove (docs/ros2.md)"),
    "export": ("dronesim.export", "main", "a journal as an MCAP file (Foxglove scene + ROS 2 topics, docs/ros2.md)"),
    "router": ("dronesim.router", "cli", "a standalone Zenoh router (for multi-host runs without zenohd)"),
    "certs": ("dronesim.certs", "cli", "a development CA and per-role TLS certificates/passwords (docs/security.md)"),
    "replay": ("dronesim.replay", "main", "re-render a run from its journal; --verify re-simulates it"),
    "bench": ("benchmarks", "cli", "benchmarks (`dronesim bench --help` lists them; results in BENCHMARKS.md)"),
}


def usage() -> str:
    lines = ["usage: dronesim COMMAND [options]   (dronesim COMMAND --help for its options)", "", "commands:"]
    lines += [f"  {name:<12} {doc}" for name, (_, _, doc) in COMMANDS.items()]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"dronesim: unknown command {name!r}\n\n{usage()}", file=sys.stderr)
        return 2
    module, func, _ = COMMANDS[name]
    return int(getattr(importlib.import_module(module), func)(rest) or 0)
