"""Integration-test harness: an embedded router on a free loopback port, entity processes, and
line-by-line waiting on their output (event-driven, no sleeps)."""

from __future__ import annotations

import contextlib
import importlib.metadata
import json
import os
import queue
import re
import shutil
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import zenoh

from dronesim import child_env
from dronesim.scenario import Scenario, swarm_hosts
from network.transport import client_config, router_config, router_locators

TIMEOUT = 60.0
#: What tests/setup.d/ scripts leave behind (downloads, the zenohd install status).
CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "dronesim"


@contextlib.contextmanager
def embedded_router(*, tgt_budgets: bool = True) -> Iterator[str]:
    """A router session in this process on tcp/127.0.0.1:<free port>; yields its locator. Without `tgt_budgets`, no
    budget of puts on the TGT keys (`schema.tuning.TGT_RATE`): for a test that puts several TGTs on one drone's key
    at once, more than a router lets through, to see what the receiving process does with each."""
    conf = router_config("tcp/127.0.0.1:0")
    if not tgt_budgets:
        puts, *rest = json.loads(conf.get_json("downsampling"))
        puts["rules"] = [r for r in puts["rules"] if not r["key_expr"].endswith("/TGT")]
        conf.insert_json5("downsampling", json.dumps([puts, *rest]))
    with zenoh.open(conf) as router:
        yield router_locators(router)[0]




def ask_until_replied(session: zenoh.Session, key: str, payload: bytes | None = None,
                      timeout: float = TIMEOUT) -> list[zenoh.Reply]:
    """The replies to a query on `key` (a CONNECT) asked right after another from the same session: a router keeps at
    most `schema.tuning.CONNECT_RATE` CONNECTs a second from one session (`schema.acl.flood_filters`) and ends a
    query it drops at once, without a reply; so it is asked again until one comes (or `timeout` s), as an entity
    does (`network.membership.Membership`)."""
    end = time.monotonic() + timeout
    while True:
        replies = list(session.get(key, payload=payload, timeout=timeout))
        if replies or time.monotonic() > end:
            return replies


def unique_root() -> str:
    return f"t{uuid.uuid4().hex[:10]}"


class Proc:
    """An entity process whose stdout and stderr lines are collected by reader threads."""

    def __init__(self, name: str, argv: list[str], log_dir: Path, stdin: int | None = subprocess.DEVNULL) -> None:
        self.name = name
        self.argv = argv
        self.lines: queue.SimpleQueue[tuple[str, str] | None] = queue.SimpleQueue()
        self.out: list[str] = []
        self.err: list[str] = []
        env = child_env(PYTHONUNBUFFERED="1")
        self.p = subprocess.Popen(argv, stdin=stdin, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                  env=env)
        self._log = log_dir / f"{name}.log"
        self._readers = [threading.Thread(target=self._read, args=(self.p.stdout, "out", self.out), daemon=True),
                         threading.Thread(target=self._read, args=(self.p.stderr, "err", self.err), daemon=True)]
        for t in self._readers:
            t.start()

    def _read(self, stream, tag: str, sink: list[str]) -> None:
        with stream:  # closed at the end of the output: no pipe left for the garbage collector to warn about
            for line in stream:
                sink.append(line.rstrip("\n"))
                self.lines.put((tag, line.rstrip("\n")))
        self.lines.put(None)

    def expect(self, pattern: str, timeout: float = TIMEOUT, *, fresh: bool = False) -> str:
        """Block until a line of output matches `pattern` (regex); AssertionError on exit or timeout.
        `fresh`: only lines not yet looked at by an earlier `expect`."""
        rx = re.compile(pattern)
        for line in () if fresh else self.out + self.err:
            if rx.search(line):
                return line
        closed = 0
        while closed < 2:
            try:
                item = self.lines.get(timeout=timeout)
            except queue.Empty:
                why = f"{self.name}: no line matching {pattern!r} within {timeout}s:\n{self.text}"
                raise AssertionError(why) from None
            if item is None:
                closed += 1
                continue
            if rx.search(item[1]):
                return item[1]
        raise AssertionError(f"{self.name} ended without a line matching {pattern!r}:\n{self.text}")

    def wait(self, timeout: float = TIMEOUT) -> int:
        try:
            code = self.p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.p.kill()
            self.p.wait()
            raise AssertionError(f"{self.name} did not exit within {timeout}s:\n{self.text}") from None
        for t in self._readers:
            t.join(timeout=10)
        self._log.write_text(self.text)
        return code

    @property
    def text(self) -> str:
        return "\n".join(["--- stdout", *self.out, "--- stderr", *self.err])

    def kill(self) -> None:
        if self.p.poll() is None:
            self.p.kill()
        self.p.wait()
        for t in self._readers:
            t.join(timeout=10)
        self._log.write_text(self.text)  # kept for a post-mortem of a failed test


class Cluster:
    """Starts entity processes against one router and one key root; kills leftovers on exit."""

    def __init__(self, locator: str, tmp: Path, root: str | None = None, log_level: str = "INFO") -> None:
        self.locator = locator
        self.tmp = tmp
        self.root = root or unique_root()
        self.log_level = log_level
        self.procs: list[Proc] = []

    def start(self, name: str, role: str, *args: str, stdin: int | None = subprocess.DEVNULL,
              netns: str | None = None, connect: str | None = None, verify_env: bool = True,
              wrap: tuple[str, ...] = ()) -> Proc:
        """Start `dronesim ROLE` as a client of the router (in network namespace `netns` if given; run by the
        command `wrap` if given, e.g. `prlimit --fsize=N`)."""
        prefix = [*(["ip", "netns", "exec", netns] if netns else []), *wrap]
        if role == "coordinator" and verify_env:  # test games also check the environment's UPD against the world
            args = ("--verify-env", *args)
        argv = [*prefix, sys.executable, "-m", "dronesim", role, "--mode", "client",
                "--connect", connect or self.locator, "--root", self.root, "--log-level", self.log_level, *args]
        proc = Proc(name, argv, self.tmp, stdin=stdin)
        self.procs.append(proc)
        return proc

    def wait_all(self, timeout: float = TIMEOUT) -> dict[str, int]:
        return {p.name: p.wait(timeout) for p in self.procs}

    def close(self) -> None:
        for p in self.procs:
            p.kill()

    def __enter__(self) -> Cluster:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def play_scenario(locator: str, tmp: Path, scenario: Path, layout: str,
                  *host_args: str, hosts: int = 1) -> tuple[Path, Proc, list[Proc]]:
    """A scenario file played to its end by real processes over `locator`: the coordinator (journal), the
    environment, the drones (`layout` "processes": one process per drone; "swarm": `hosts` hosts per autopilot
    (H01, H02, ...), its drones split in id order, with `host_args`) and a scripted ground station; every process
    must exit 0. The journal, the coordinator's process and every process (their output stays readable)."""
    autopilots = Scenario.load(scenario).autopilots
    journal = tmp / f"{layout}.journal"
    with Cluster(locator, tmp, log_level="WARNING") as c:
        srv = c.start("SRV", "coordinator", "--scenario", str(scenario), "--journal", str(journal),
                      "--admit-deadline", "120", "--log-level", "INFO")
        srv.expect("coordinator ready")
        c.start("ENV", "env", "--no-draw")
        if layout == "processes":  # one process per drone
            for d, pilot in sorted(autopilots.items()):
                c.start(d, "drone", "--id", d, "--autopilot", pilot)
        else:  # `hosts` swarm hosts per autopilot
            number = 0
            for pilot, ids in swarm_hosts(autopilots).values():
                for part in (ids[k * len(ids) // hosts:(k + 1) * len(ids) // hosts] for k in range(hosts)):
                    number += 1
                    host = f"H{number:02d}"
                    c.start(host, "drone", "--id", ",".join(part), "--host", host, "--autopilot", pilot, *host_args)
        c.start("GCS", "gcs", "--scenario", str(scenario), "--quiet")
        codes = c.wait_all(timeout=240)
        assert set(codes.values()) == {0}, [p.text for p in c.procs if p.p.returncode]
        return journal, srv, list(c.procs)


class Hosts:
    """Test hosts as network namespaces: a router host joined by veth links to each other host.

    Host `name` gets the link 10.231.<i>.2/24 and the router host 10.231.<i>.1/24 on its side: every
    address belongs to these namespaces, nothing leaves the machine. `cut(name)`/`restore(name)` take a
    host's link down and up."""

    def __init__(self, *hosts: str) -> None:
        self.tag = uuid.uuid4().hex[:6]
        self.router = f"dsr{self.tag}"
        self.hosts = {h: f"ds{h.lower()}{self.tag}" for h in hosts}
        self.addr: dict[str, str] = {}

    def _ip(self, *args: str) -> None:
        subprocess.run(["ip", *args], check=True, capture_output=True, text=True)

    def __enter__(self) -> Hosts:
        try:
            self._ip("netns", "add", self.router)
            self._ip("-n", self.router, "link", "set", "lo", "up")
            for i, (host, ns) in enumerate(self.hosts.items(), 1):
                self._ip("netns", "add", ns)
                self._ip("-n", ns, "link", "set", "lo", "up")
                a, b = f"vr{i}{self.tag}", f"vh{i}{self.tag}"
                self._ip("link", "add", a, "netns", self.router, "type", "veth", "peer", "name", b, "netns", ns)
                self._ip("-n", self.router, "addr", "add", f"10.231.{i}.1/24", "dev", a)
                self._ip("-n", ns, "addr", "add", f"10.231.{i}.2/24", "dev", b)
                self._ip("-n", self.router, "link", "set", a, "up")
                self._ip("-n", ns, "link", "set", b, "up")
                self.addr[host] = f"10.231.{i}.1"  # where that host reaches the router
        except BaseException:
            self.__exit__()
            raise
        return self

    def ns(self, host: str) -> str:
        return self.hosts[host]

    def _link(self, host: str) -> str:
        return f"vh{list(self.hosts).index(host) + 1}{self.tag}"

    def cut(self, host: str) -> None:
        self._ip("-n", self.hosts[host], "link", "set", self._link(host), "down")

    def restore(self, host: str) -> None:
        self._ip("-n", self.hosts[host], "link", "set", self._link(host), "up")

    def __exit__(self, *exc: object) -> None:
        for ns in [*self.hosts.values(), self.router]:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def play_to_the_end(cluster: Cluster, targets: dict[str, tuple[int, int, int]]) -> None:
    """The test plays the ground station of `cluster`'s game to OVER; every process must exit 0."""
    gcs = ScriptedGCS(cluster.locator, cluster.root, targets)
    try:
        gcs.play_until()
    finally:
        gcs.close()
    codes = cluster.wait_all()
    assert set(codes.values()) == {0}, [p.text for p in cluster.procs]


def journal_records(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line]


class ScriptedGCS:
    """The test itself as the ground station: it answers each GCS phase only when told to, so a test can
    act at an exact point of the game (kill a process between two turns) without racing it."""

    def __init__(self, locator: str, root: str, targets: dict[str, tuple[int, int, int]], *,
                 intent: str = "FINAL") -> None:
        import logging

        from network.membership import Membership
        from network.transport import Inbox, Outbox, session_id
        from schema import Connect, Intent, Keys, Over, Role, Status, Turn

        self.keys = Keys(root)
        self.targets = dict(targets)
        self.intent = Intent(intent)
        self.log = logging.getLogger("dronesim.tests.gcs")
        self._cm = zenoh.open(client_config(locator))
        self.session = self._cm.__enter__()
        self.inbox = Inbox(self.session, self.keys, self.log)
        for key, typ in ((self.keys.turn, Turn), (self.keys.status, Status), (self.keys.over, Over)):
            self.inbox.subscribe(key, typ)
        self.out = Outbox(self.session)
        self.member = Membership(self.session, self.inbox, Connect(turn=0, sender="GCS", role=Role.GCS,
                                                                   session=session_id(self.session)),
                                 self.log, connect_timeout=TIMEOUT, grace=TIMEOUT)
        self.statuses: list = []
        self.over = None

    def next_event(self, timeout: float = TIMEOUT):
        from network.membership import Answered
        from network.transport import Presence, Received
        from schema import Over, Status

        ev = self.inbox.get(timeout)
        if ev is None:
            raise AssertionError("the game stalled: no event")
        match ev:
            case Presence() | Answered():
                self.member.on_event(ev)
            case Received(_, Status() as st):
                self.statuses.append(st)
            case Received(_, Over() as over):
                self.over = over
        return ev

    def wait_phase(self, phase: str, turn: int | None = None, timeout: float = TIMEOUT):
        """Block until TURN(turn, phase) arrives (any turn if None); returns it (None if the game ended)."""
        from network.transport import Received
        from schema import Turn

        while self.over is None:
            ev = self.next_event(timeout)
            if isinstance(ev, Received) and isinstance(ev.msg, Turn) and ev.msg.phase.value == phase:
                if turn is None or ev.msg.turn == turn:
                    return ev.msg
        return None

    def answer(self, turn: int) -> None:
        from schema import Done, Phase, Target

        alive = {s.drone for s in self.statuses[-1].drones if s.alive} if self.statuses else set(self.targets)
        sent = 0
        for d, cell in sorted(self.targets.items()):
            if d in alive:
                self.out.put(self.keys.tgt(d), Target(turn=turn, sender="GCS", drone=d, pos=cell))
                sent += 1
        self.out.put(self.keys.gcs_done, Done(turn=turn, sender="GCS", phase=Phase.GCS, intent=self.intent,
                                              count=sent))

    def play_until(self, turn: int | None = None) -> None:
        """Answer every GCS phase up to and including `turn` (None: to the end of the game)."""
        while self.over is None:
            t = self.wait_phase("GCS")
            if t is None:
                return
            self.answer(t.turn)
            if turn is not None and t.turn >= turn:
                return

    def close(self) -> None:
        self.member.close()
        self._cm.__exit__(None, None, None)


def zenohd_binary() -> Path | None:
    """zenohd on PATH, or where tests/setup.d/zenohd.sh installs it (cargo's bin); None if neither."""
    found = shutil.which("zenohd")
    candidates = [Path(found)] if found else []
    candidates.append(Path(os.environ.get("CARGO_HOME", Path.home() / ".cargo")) / "bin" / "zenohd")
    return next((c for c in candidates if c.exists()), None)


@contextlib.contextmanager
def zenohd(conf: Path, locator: str, tmp: Path, name: str = "zenohd") -> Iterator[str]:
    """zenohd, of the installed eclipse-zenoh's version, running `conf`, which listens on `locator`;
    yields the locator once zenohd says it can be reached there. Skips, saying why, where zenohd is
    missing or another version."""
    import pytest

    binary = zenohd_binary()
    if binary is None:
        status = CACHE / "zenohd-install.txt"
        why = status.read_text().strip() if status.exists() else "tests/setup.d/zenohd.sh has not run"
        print(f"zenohd is not on PATH ({why}): skipping the zenohd router")
        pytest.skip(f"zenohd is not installed ({why})")
    pin = importlib.metadata.version("eclipse-zenoh")
    version = subprocess.run([str(binary), "--version"], capture_output=True, text=True, timeout=30).stdout
    if f"v{pin} " not in version:
        print(f"{binary} is {version.strip()!r}, not {pin}: skipping the zenohd router")
        pytest.skip(f"{binary} is {version.strip()!r}, not {pin}: run bash tests/setup.d/zenohd.sh")
    proc = Proc(name, ["env", "RUST_LOG=info", str(binary), "-c", str(conf)], tmp)
    try:
        # not just configured: zenohd logs its whole config (listen endpoint included) before it listens
        proc.expect(rf"can be reached at: {re.escape(locator)}", timeout=60)
        yield locator
    finally:
        proc.p.terminate()
        try:
            proc.p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
