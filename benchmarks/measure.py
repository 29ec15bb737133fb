"""What the benchmarks measure with and around: the machine, the processes' CPU and memory, a loopback router
process, child processes with their logs, and the table every benchmark writes (`Row`, `render`, `verdict`)."""

from __future__ import annotations

import contextlib
import importlib.metadata
import os
import platform
import re
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dronesim import child_env


def pct(values: Sequence[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def mib(kib: int | None) -> str:
    return "-" if kib is None else f"{kib / 1024:.0f}"


def size_text(size: Sequence[int]) -> str:
    return "x".join(map(str, size))


def bytes_text(n: int) -> str:
    if n < 1024 * 1024:
        return f"{n / 1024:.1f} KiB"
    return f"{n / 1024 / 1024:.1f} MiB"


def proc_status(pid: int) -> dict[str, int]:
    """VmHWM, VmRSS... of a process, in KiB (empty if it is gone)."""
    out: dict[str, int] = {}
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Vm") and line.rstrip().endswith("kB"):
                    name, value = line.split(":", 1)
                    out[name] = int(value.split()[0])
    except OSError:
        pass
    return out


def cpu_seconds(pid: int | str = "self") -> float:
    """User + system CPU time of a process (all its threads) so far, in seconds (nan if it is gone)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime


def busy_seconds() -> tuple[float, float]:
    """(CPU seconds every process of the machine used so far, this process and its waited-for children's)."""
    fields = [int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)  # idle + iowait
    mine = os.times()
    total = (sum(fields[:8]) - idle) / os.sysconf("SC_CLK_TCK")  # user..steal; guest time is inside user
    return total, mine.user + mine.system + mine.children_user + mine.children_system


def machine() -> dict[str, str]:
    cpu = platform.processor() or platform.machine()
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    try:
        zv = importlib.metadata.version("eclipse-zenoh")
    except importlib.metadata.PackageNotFoundError:
        zv = "?"
    return {"nproc": str(os.cpu_count()), "cpu": cpu, "python": platform.python_version(), "zenoh": zv,
            "arch": platform.machine()}


@dataclass(frozen=True, slots=True)
class Router:
    locator: str
    pid: int


@contextlib.contextmanager
def loopback_router(config: Path | None = None, *, scheme: str = "tcp", flags: Sequence[str] = ()) -> Iterator[Router]:
    """A Zenoh router process (`dronesim router`) on <scheme>/127.0.0.1:<free port>, loopback only, as in a
    deployment: no entity shares its process (an entity's Python callbacks run on Zenoh's threads and
    would hold up a router living in the same process), in a session of its own (as `Procs`); `config`: its zenoh
    configuration file; `flags`: more of `dronesim router`'s (e.g. `Secured.router_flags`)."""
    conf = ["--config", str(config)] if config is not None else []
    p = subprocess.Popen([sys.executable, "-m", "dronesim", "router", "--listen", f"{scheme}/127.0.0.1:0", *conf,
                          *flags, "--log-level", "WARNING"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                         text=True, env=child_env(), start_new_session=True)
    try:
        line = p.stdout.readline() if p.stdout else ""
        found = re.search(rf"listening on ({scheme}/127\.0\.0\.1:\d+)", line)
        if not found:
            raise RuntimeError(f"the router did not start on loopback: {line!r}")
        yield Router(found.group(1), p.pid)
    finally:
        p.terminate()
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


class Procs:
    """Child processes with their output in log files (no reader threads in this process), each in a session of its
    own as `dronesim up` starts the game's processes (Linux schedules each session as a group, autogroup: measured in
    one session, the game's processes shared one group's share of the machine, which no deployment does)."""

    def __init__(self, logs: Path) -> None:
        self.logs = logs
        self.procs: dict[str, subprocess.Popen] = {}
        self._files: list = []

    def start(self, name: str, argv: list[str]) -> subprocess.Popen:
        log = open(self.logs / f"{name}.log", "w", encoding="utf-8")  # noqa: SIM115 - closed in close()
        self._files.append(log)
        p = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                             env=child_env(PYTHONUNBUFFERED="1"), start_new_session=True)
        self.procs[name] = p
        return p

    def dead(self) -> list[str]:
        return [f"{n} exited {p.returncode}" for n, p in self.procs.items() if p.poll() is not None]

    def wait(self, timeout: float) -> dict[str, int | None]:
        end = time.monotonic() + timeout
        codes: dict[str, int | None] = {}
        for name, p in self.procs.items():
            try:
                codes[name] = p.wait(max(0.1, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                codes[name] = None
        return codes

    def tail(self, name: str, lines: int = 15) -> str:
        with contextlib.suppress(OSError):
            return "\n".join((self.logs / f"{name}.log").read_text(errors="replace").splitlines()[-lines:])
        return ""

    def close(self) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
        for f in self._files:
            f.close()


@dataclass(slots=True)
class Row:
    name: str
    cells: dict[str, str] = field(default_factory=dict)
    ok: bool = True  # every process exited 0 (or nothing to check)


def render(rows: list[Row], columns: tuple[tuple[str, str], ...]) -> str:
    lines = ["| " + " | ".join(h for _, h in columns) + " |", "|" + "---|" * len(columns)]
    for r in rows:
        vals = [r.name] + [r.cells.get(k, "") for k, _ in columns[1:]]
        lines.append("| " + " | ".join(v.replace("|", "/") if v else "—" for v in vals) + " |")
    return "\n".join(lines)


def verdict(value: float, target: float, at_most: bool, what: str) -> str:
    if value != value:  # nan
        return f"{what}: not measured"
    met = value <= target if at_most else value >= target
    return f"{what}: {'met' if met else 'UNMET'}"


def await_presence(session, key: str, timeout: float) -> bool:
    """Block until a liveliness token matching `key` exists (True) or `timeout` passes (False): a benchmark waiting
    for a process it started (an entity never waits so: it takes presences as events, network/membership.py)."""
    seen = threading.Event()
    sub = session.liveliness().declare_subscriber(key, lambda s: seen.set(), history=True)
    try:
        return seen.wait(max(0.0, timeout))
    finally:
        sub.undeclare()
