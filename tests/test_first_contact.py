"""What a user meets first (issue 33, item 8): an unreachable router, a replica claiming a taken drone id, a
PettingZoo environment left open, `dronesim up --phase-deadline`."""

from __future__ import annotations

import logging
import subprocess
import sys
import textwrap

import pytest

from coordinator.engine import Engine
from dronesim import child_env
from dronesim.up import build_parser, coordinator_flags
from schema import Connect, Refused, Role

from .test_engine import config, reply

UNREACHABLE = "tcp/127.0.0.1:1"


@pytest.mark.parametrize("command", [
    ["coordinator"], ["coordinator", "--mode", "client"], ["env"], ["env", "--mode", "client"],
    ["drone", "--id", "D01"],
    ["drone", "--id", "D01-D02", "--host", "H01", "--mode", "client"], ["gcs", "--targets", "1,1,1"],
    ["gcs", "--web", "127.0.0.1:0"], ["router", "--listen", "tcp/127.0.0.1:0"], ["ros2"],
])
def test_an_unreachable_router_is_one_line_and_exit_2(command: list[str]) -> None:
    """Every command given a router it cannot reach (in any mode: a peer used to wait for it forever, a client
    printed a traceback) says so in one line and exits 2."""
    done = subprocess.run([sys.executable, "-m", "dronesim", *command, "--connect", UNREACHABLE],
                          capture_output=True, text=True, env=child_env(), timeout=60, stdin=subprocess.DEVNULL)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2, done.stderr
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert "cannot open a Zenoh session" in lines[0] and "127.0.0.1:1" in lines[0] and ".rs:" not in lines[0]


def test_dronesim_up_that_cannot_listen_is_one_line_and_exit_2() -> None:
    done = subprocess.run([sys.executable, "-m", "dronesim", "up", "--listen", "tcp/203.0.113.9:0", "--targets",
                           "1,1,1"], capture_output=True, text=True, env=child_env(), timeout=60)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.strip().count("\n") == 0 and "cannot open a Zenoh session" in done.stderr


def test_the_rl_zenoh_backend_says_in_one_line_that_the_router_cannot_be_reached() -> None:
    from dronesim.rl import BackendError
    from dronesim.rl_zenoh import ZenohTurns

    with pytest.raises(BackendError, match=r"cannot open a session with the Zenoh router at tcp/127\.0\.0\.1:1") as err:
        ZenohTurns(connect=UNREACHABLE)
    assert ".rs:" not in str(err.value) and "\n" not in str(err.value)


def test_a_drone_id_already_taken_is_refused_quietly_a_duplicate_role_is_not(caplog) -> None:
    """Drone replicas claim ids in turn (docker/entrypoint.py): a taken id is refused at INFO, as expected; a second
    environment or ground station still warns."""
    e = Engine(config(("D01", (0, 0, 0)), ("D02", (1, 0, 0))), logging.getLogger("dronesim.tests.first"))
    e.connect(Connect(turn=0, sender="ENV", role=Role.ENV), 1)
    e.connect(Connect(turn=0, sender="D01", role=Role.DRONE, drones=("D01",), autopilot="seed", session="a"), 2)
    with caplog.at_level(logging.INFO, logger="dronesim.tests.first"):
        again = reply(e.connect(Connect(turn=0, sender="D01", role=Role.DRONE, drones=("D01",), autopilot="seed",
                                        session="b"), 3))
        env = reply(e.connect(Connect(turn=0, sender="ENV", role=Role.ENV, session="c"), 4))
    assert isinstance(again, Refused) and "D01 is already connected" in again.text
    assert isinstance(env, Refused)
    levels = {r.getMessage().split(":")[0]: r.levelno for r in caplog.records if r.getMessage().startswith("refused")}
    assert levels == {"refused D01": logging.INFO, "refused ENV": logging.WARNING}


def test_dronesim_up_offers_the_phase_deadline() -> None:
    flags = coordinator_flags(build_parser().parse_args(["--phase-deadline", "30"]), "tcp/127.0.0.1:7447")
    assert flags[flags.index("--phase-deadline") + 1] == "30.0"
    assert "--phase-deadline" not in coordinator_flags(build_parser().parse_args([]), "tcp/127.0.0.1:7447")


@pytest.mark.parametrize("ending", ["return", "raise"])
@pytest.mark.parametrize("form", ["parallel_env", "env"])
def test_a_zenoh_pettingzoo_env_left_open_does_not_keep_python_alive(form: str, ending: str) -> None:
    """A script that ends (or raises) mid-episode without close() exits, and leaves no process behind."""
    pytest.importorskip("pettingzoo")
    script = textwrap.dedent(f"""
        import dronesim.pettingzoo as dz
        e = dz.{form}(backend="zenoh", num_drones=2, seed=3, deadline=20)
        e.reset(seed=3)
        if {form!r} == "env":
            e.step(0)
        else:
            e.step({{a: 0 for a in e.agents}})
        print("mid-episode", flush=True)
        if {ending!r} == "raise":
            raise RuntimeError("the script fails mid-episode")
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=child_env())
    try:
        out, err = proc.communicate(timeout=90)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"the script did not exit: {out} {err[-2000:]}")
    assert "mid-episode" in out, err[-2000:]
    assert proc.returncode == (1 if ending == "raise" else 0), err[-2000:]


class Events:
    """What `supervise` uses of an `Inbox`: events posted from any thread, taken in order."""

    def __init__(self) -> None:
        import queue
        self._queue: queue.SimpleQueue = queue.SimpleQueue()

    def post(self, event: object) -> None:
        self._queue.put(event)

    def get(self, timeout: float | None = None) -> object:
        return self._queue.get(timeout=timeout)


class FakeProcess:
    """A process `supervise` starts: it runs until `end(code)`."""

    def __init__(self) -> None:
        import threading
        self._ended, self.returncode = threading.Event(), None

    def end(self, code: int) -> None:
        self.returncode = code
        self._ended.set()

    def wait(self, timeout: float | None = None) -> int:
        self._ended.wait(timeout)
        return self.returncode

    def poll(self) -> int | None:
        return self.returncode

    def send_signal(self, signum: int) -> None:
        self.end(128 + signum)


def test_dronesim_up_starts_its_processes_a_window_at_a_time() -> None:
    """`dronesim up --drones 400` started every process at once: their sessions overran the router's pending
    handshakes on 2 cores, a hundred never connected and the game ended ABORTED. At most `window` of them are now
    started and neither connected (a presence token seen) nor ended; each that connects or ends lets the next start."""
    import queue
    import threading

    from dronesim.up import supervise
    from network.transport import Presence

    names = ["SRV", "ENV", *(f"D{i:02d}" for i in range(1, 7)), "GCS"]
    window, released = 3, set[str]()
    started: queue.SimpleQueue[tuple[str, FakeProcess]] = queue.SimpleQueue()
    events = Events()  # (an `Inbox`'s: the events posted, presences among them)

    def launch(name: str, argv: list[str]) -> FakeProcess:
        unreleased = [n for n, _ in running if n not in released]
        assert len(unreleased) < window, (name, unreleased)  # (a launch beyond the window fails the run)
        proc = FakeProcess()
        started.put((name, proc))
        return proc

    running: list = []
    codes: dict = {}
    t = threading.Thread(target=lambda: codes.update(supervise([(n, [n]) for n in names], launch, running, events,
                                                               window)))
    t.start()
    procs = dict(started.get(timeout=60) for _ in range(window))
    assert list(procs) == names[:window]
    for name in names[window:]:  # each presence, then each end, lets one more start, in order
        first = next(n for n in procs if n not in released)
        released.add(first)
        if len(released) % 2:
            events.post(Presence(first, "s1", True))
        else:
            procs[first].end(0)  # (its waiting thread says so)
        new, proc = started.get(timeout=60)
        assert new == name
        procs[new] = proc
    for name, proc in procs.items():
        released.add(name)
        proc.end(0)
    t.join(60)
    assert codes == dict.fromkeys(names, 0)
    assert started.empty()


def test_dronesim_up_with_a_window_of_one_sees_each_process_connect_through_its_secured_router() -> None:
    """The window is released by the presence tokens `dronesim up`'s own router sees through the game's TLS and
    access control: one process at a time, the game plays to its end."""
    code = textwrap.dedent("""
        import sys
        import dronesim.up as up
        up.UP_START_WINDOW = 1
        sys.exit(up.cli(["--seed", "7", "--drones", "3", "--targets", "9,9,0", "--quiet", "--max-turns", "40"]))
    """)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                       stdin=subprocess.DEVNULL, env=child_env())
    assert p.returncode == 0, p.stdout + p.stderr
    assert "all 6 processes exited 0" in p.stdout
