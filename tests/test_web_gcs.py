"""The web ground station without a browser: its pure model (pacing, checks, events), the replay frames,
the HTTP server against a fake backend (every bad input a 4xx JSON error, never a crash), the bridge
between HTTP threads and the main thread, and -- marked integration -- whole games driven over HTTP/SSE
with a real router and real entity processes. The browser tests are in tests/e2e/."""

from __future__ import annotations

import http.client
import json
import logging
import queue
import re
import signal
import socket
import sys
import threading
from pathlib import Path

import pytest

from coordinator.config import DroneSpec, GameConfig
from coordinator.journal import dumps
from dronesim.local import Inputs, simulate
from entities.gcs import Ground, Plan, SendDone
from entities.web import node as web_node
from entities.web import server as web_server
from entities.web.model import GroundState, Rejected, parse_cell, world_json
from entities.web.replay import Replay
from entities.web.server import Hub, WebServer, parse_address
from schema import (
    Cause,
    DroneState,
    DroneStatus,
    EndReason,
    Intent,
    Note,
    Over,
    Phase,
    Status,
    Turn,
    UsageError,
    WorldSpec,
)
from world.grid import Building, World

LOG = logging.getLogger("dronesim.tests.web")
WALL = World.from_buildings((5, 5, 2), [Building(x=2, y=0, length=1, width=5, height=1)])


# --------------------------------------------------------------------------- helpers


def status(turn: int, *drones: DroneStatus) -> Status:
    return Status(turn=turn, sender="OBS", drones=drones)


def ds(drone="D01", pos=(0, 0, 0), state=DroneState.ALIVE, target=None, note=Note.NONE, cause=Cause.NONE):
    return DroneStatus(drone=drone, pos=pos, state=state, target=target, note=note, cause=cause)


def gcs_turn(t: int) -> Turn:
    return Turn(turn=t, sender="SRV", phase=Phase.GCS)


NO_PLAN = Plan(())


def started(pace: float = 0.5, drones=("D01", "D02"), plan: Plan = NO_PLAN) -> GroundState:
    """A state at turn 1's GCS phase, STATUS(0) in, nothing targeted."""
    starts = {d: (0, 2 * i, 0) for i, d in enumerate(drones)}
    g = GroundState(Ground(WALL, starts, plan), pace=pace)
    g.receive(status(0, *(ds(d, p) for d, p in starts.items())), 100.0)
    g.receive(gcs_turn(1), 100.0)
    return g


def answer(g: GroundState, now: float) -> tuple[int, dict, Intent]:
    """The pending phase answered: its DONE's turn, the targets it carries (those that change), its intent."""
    [send] = g.answer(now)
    assert isinstance(send, SendDone)
    return send.msg.turn, {a.drone: a.pos for a in send.msg.targets}, send.msg.intent


# --------------------------------------------------------------------------- the model


@pytest.mark.parametrize("text,cell", [("1,2,3", (1, 2, 3)), (" 1 2 3 ", (1, 2, 3)), ("(4, 0, 1)", (4, 0, 1)),
                                       ("-1,0,0", (-1, 0, 0))])
def test_parse_cell_accepts_text_forms(text, cell):
    assert parse_cell(text) == cell


@pytest.mark.parametrize("bad", ["1,2", "a,b,c", "1,2,3,4", "", [1, 2], [1, 2, 3.0], [True, 0, 0], {"x": 1}, None,
                                 ["1", "2", "3"], "\uff11,2,3", "9" * 5000 + ",1,0", "1234567890,0,0",
                                 [10 ** 9, 0, 0], [0, -(10 ** 40), 0]])
def test_parse_cell_refuses_anything_else_with_400(bad):
    with pytest.raises(Rejected) as err:
        parse_cell(bad)
    assert err.value.status == 400 and "x" in err.value.text


def test_world_json_draws_floors_as_the_seed_does():
    w = world_json(WALL, mode="live")
    assert w["size"] == [5, 5, 2]
    assert w["floors"][0] == [".....", ".....", "#####", ".....", "....."]  # row = x: the wall is row 2
    assert w["floors"][1] == ["....."] * 5
    assert w["building_cells"] == 5


def test_holds_the_gcs_phase_until_a_first_target():
    g = started()
    assert g.waiting()[0] == "target"
    assert g.due(100.0) is None  # held: no timer at all
    g.set_target("D01", (4, 4, 0))
    assert g.due(100.0) == 0.0
    turn, targets, intent = answer(g, 100.0)
    assert (turn, targets, intent) == (1, {"D01": (4, 4, 0)}, Intent.CONTINUE)
    assert g.due(100.0) is None  # answered: nothing pending


def test_answers_at_the_pace_with_the_targets_that_change():
    g = started(pace=0.5)
    g.set_target("D01", (4, 4, 0))
    g.set_target("D02", (4, 0, 1))
    assert answer(g, 100.0) == (1, {"D01": (4, 4, 0), "D02": (4, 0, 1)}, Intent.CONTINUE)
    g.receive(status(1, ds("D01", (1, 0, 0), target=(4, 4, 0)), ds("D02", (0, 2, 1), target=(4, 0, 1))), 0.0)
    g.receive(gcs_turn(2), 100.1)
    assert g.due(100.1) == pytest.approx(0.4)  # the pace, from the last answer
    g.set_target("D02", (3, 0, 1))
    assert answer(g, 100.5) == (2, {"D02": (3, 0, 1)}, Intent.CONTINUE)  # D01's is in force already
    assert g.wanted == {"D01": (4, 4, 0), "D02": (3, 0, 1)}


def test_waits_for_the_previous_turns_status_before_deciding():
    g = started(pace=0)
    g.set_target("D01", (4, 4, 0))
    answer(g, 100.0)
    g.receive(gcs_turn(2), 101.0)  # TURN(2) overtook STATUS(1) (different keys)
    assert g.due(101.0) == pytest.approx(2.0)  # bounded wait for it
    g.receive(status(1, ds("D01", (0, 0, 0), target=(4, 4, 0), note=Note.REACHED), ds("D02", (0, 2, 0))), 0.0)
    assert g.status_turn == 1


def test_holds_when_every_drone_is_at_its_target_and_step_or_a_new_target_resumes():
    g = started(pace=0)
    g.set_target("D01", (1, 0, 0))
    answer(g, 100.0)
    g.receive(status(1, ds("D01", (1, 0, 0), target=(1, 0, 0), note=Note.REACHED), ds("D02", (0, 2, 0))), 0.0)
    g.receive(gcs_turn(2), 100.0)
    assert g.due(100.0) is None and g.waiting()[0] == "idle"
    assert any(e["kind"] == "reached" and "D01 reached its target (1, 0, 0)" in e["text"] for e in g.log)
    g.control("step")
    assert g.due(100.0) == 0.0
    assert answer(g, 100.0)[1] == {} and g.wanted == {"D01": (1, 0, 0)}  # in force already
    g.receive(status(2, ds("D01", (1, 0, 0), target=(1, 0, 0), note=Note.REACHED), ds("D02", (0, 2, 0))), 0.0)
    g.receive(gcs_turn(3), 100.0)
    assert g.due(100.0) is None
    g.set_target("D01", (3, 3, 1))  # a changed target is work to do
    assert g.due(100.0) == 0.0


def test_unreachable_target_holds_too():
    g = started(pace=0)
    g.set_target("D01", (4, 4, 0))  # (the drone will find no way there)
    answer(g, 100.0)
    g.receive(status(1, ds("D01", (1, 0, 0), target=(4, 4, 0), note=Note.UNREACHABLE), ds("D02", (0, 2, 0))), 0.0)
    g.receive(gcs_turn(2), 100.0)
    assert g.due(100.0) is None
    assert g.snapshot()["drones"][0]["status"] == "unreachable"


def test_pause_holds_and_quit_ends_even_when_paused():
    g = started(pace=0)
    g.set_target("D01", (4, 4, 0))
    g.control("pause")
    assert g.due(100.0) is None and g.waiting()[0] == "paused"
    g.control("resume")
    assert g.due(100.0) == 0.0
    g.control("pause")
    g.control("quit")
    assert g.due(100.0) == 0.0
    turn, targets, intent = answer(g, 100.0)
    assert intent is Intent.QUIT and targets == {"D01": (4, 4, 0)}
    g.receive(gcs_turn(2), 100.0)  # whatever comes next, the QUIT is said once
    assert g.due(100.0) is None


@pytest.mark.parametrize("drone,cell,status_code,text", [
    ("D01", (5, 0, 0), 422, "(5, 0, 0) is outside the world: 0 <= x < 5, 0 <= y < 5, 0 <= z < 2"),
    ("D01", (0, -1, 0), 422, "outside the world"),
    ("D01", (0, 0, 2), 422, "outside the world"),
    ("D01", (2, 2, 0), 422, "(2, 2, 0) is inside a building: no drone can get there"),
    ("D07", (1, 1, 0), 422, "unknown drone D07: this game flies D01, D02"),
    ("X1", (1, 1, 0), 400, "is not a drone id"),
    (None, (1, 1, 0), 400, "is not a drone id"),
])
def test_invalid_targets_are_refused_with_a_clear_message(drone, cell, status_code, text):
    g = started()
    with pytest.raises(Rejected) as err:
        g.set_target(drone, cell)
    assert err.value.status == status_code and text in err.value.text
    assert g.wanted == {}


def test_deaths_and_losses_are_logged_with_their_cause_and_refuse_targets():
    g = started()
    g.set_target("D01", (4, 0, 0))
    g.set_target("D02", (4, 2, 0))
    answer(g, 100.0)
    g.receive(status(1, ds("D01", (1, 0, 0), target=(4, 0, 0)), ds("D02", (1, 2, 0), target=(4, 2, 0))), 0.0)
    g.receive(status(2, ds("D01", (2, 0, 0), DroneState.DEAD, (4, 0, 0), cause=Cause.BUILDING),
                       ds("D02", (1, 2, 0), DroneState.LOST, (4, 2, 0), cause=Cause.LOST)), 0.0)
    texts = [e["text"] for e in g.log]
    assert "D01 died at (2, 0, 0): crashed into a building" in texts
    assert "D02 is LOST at (1, 2, 0): missed its deadlines or its process vanished" in texts
    assert g.wanted == {}  # nothing more is sent to them
    with pytest.raises(Rejected, match="D01 is dead: it takes no more targets"):
        g.set_target("D01", (0, 0, 0))
    snap = g.snapshot()
    assert [(d["status"], d["cause"]) for d in snap["drones"]] == [("dead", "building"), ("lost", "lost")]
    assert snap["drones"][0]["trail"] == [[0, 0, 0], [1, 0, 0], [2, 0, 0]]
    g.receive(Over(turn=2, sender="SRV", reason=EndReason.NO_DRONE_ALIVE, text="no drone alive"), 0.0)
    assert g.log[-1] == {"turn": 2, "kind": "over", "text": "GAME OVER at turn 2: NO_DRONE_ALIVE - no drone alive"}
    with pytest.raises(Rejected) as err:
        g.set_target("D01", (0, 0, 0))
    assert err.value.status == 409
    with pytest.raises(Rejected):
        g.control("step")
    assert g.waiting()[0] == "over" and g.due(100.0) is None
    json.dumps(g.snapshot())  # JSON-able as it is


def test_collision_causes_read_as_collisions():
    g = started()
    g.receive(status(1, ds("D01", (0, 1, 0), DroneState.DEAD, cause=Cause.VERTEX),
                       ds("D02", (0, 1, 0), DroneState.DEAD, cause=Cause.SWAP)), 0.0)
    assert "D01 died at (0, 1, 0): collided with another drone (same cell)" in [e["text"] for e in g.log]
    assert "swapped cells" in g.log[-1]["text"]


def test_a_late_ground_station_takes_over_the_targets_in_force():
    g = GroundState(Ground(WALL, {"D01": (0, 0, 0)}, NO_PLAN))
    g.receive(status(6, ds("D01", (1, 1, 0), target=(4, 4, 1))), 0.0)
    assert g.wanted == {"D01": (4, 4, 1)}
    g.receive(gcs_turn(7), 0.0)
    assert g.due(0.0) == 0.0  # it has work to do: the drone is on its way
    assert answer(g, 0.0) == (7, {}, Intent.CONTINUE)  # its target is in force: nothing to send


def test_stale_messages_do_not_go_back_in_time():
    g = started()
    g.receive(status(3, ds("D01", (1, 0, 0)), ds("D02", (0, 2, 0))), 0.0)
    g.receive(status(2, ds("D01", (0, 0, 0)), ds("D02", (0, 2, 0))), 0.0)
    assert g.drones["D01"].pos == (1, 0, 0)
    g.receive(gcs_turn(4), 0.0)
    g.receive(gcs_turn(3), 0.0)
    assert g.turn == 4 and g.pending == 4


def test_a_phase_the_coordinator_closed_without_us_is_no_longer_pending():
    g = started()
    g.receive(Turn(turn=1, sender="SRV", phase=Phase.DRONES), 0.0)  # its GCS deadline passed
    assert g.pending is None and g.due(0.0) is None


def test_scripted_targets_keep_the_turns_going_until_their_last_turn():
    g = started(pace=0, plan=Plan.parse(["D02=3,3,0@3"], WALL.size))
    assert g.busy() and g.due(0.0) == 0.0  # nothing targeted yet, but turn 3 must come
    answer(g, 0.0)
    g.receive(status(1, ds("D01"), ds("D02", (0, 2, 0))), 0.0)
    g.receive(gcs_turn(3), 0.0)
    assert g.wanted == {"D02": (3, 3, 0)}
    assert g.log[-1]["text"] == "scripted target of D02: (3, 3, 0)"
    assert answer(g, 0.0) == (3, {"D02": (3, 3, 0)}, Intent.CONTINUE)
    g.receive(gcs_turn(3), 0.0)  # a repeat of an answered phase is not answered again
    assert g.pending is None and g.due(0.0) is None


@pytest.mark.parametrize("value", [-1, 11, "fast", None, True, 10 ** 400, float("nan"), float("inf")])
def test_pace_is_checked(value):
    with pytest.raises(Rejected) as err:
        started().control("pace", value)
    assert err.value.status == 400


def test_unknown_control_action_is_refused():
    with pytest.raises(Rejected, match="unknown action"):
        started().control("explode")


def test_log_and_trails_stay_bounded():
    from entities.web import model

    g = GroundState(Ground(World.from_buildings((40, 40, 1), []), {"D01": (0, 0, 0)}, Plan(())))
    for t in range(1, 700):
        g.receive(status(t, ds("D01", (t % 40, (t // 40) % 40, 0), target=(39, 39, 0))), 0.0)
        g.note("info", f"event {t}")
    snap = g.snapshot()
    assert len(snap["log"]) == model.LOG_LIMIT
    assert len(snap["drones"][0]["trail"]) <= model.TRAIL_LIMIT


# --------------------------------------------------------------------------- replay


def write_journal(path: Path, world: World, drones: dict, autopilots: dict, targets: list[str],
                  quit_at: int | None = None) -> list[dict]:
    spec = WorldSpec(size=world.size, cells=world.packed())
    config = GameConfig(world=spec, drones=tuple(DroneSpec(drone=d, start=c) for d, c in drones.items()),
                        max_turns=60)
    intents = {quit_at: Intent.QUIT} if quit_at else {}
    result = simulate(config, autopilots, Inputs(plan=Plan.parse(targets, world.size), intents=intents), LOG)
    path.write_text("".join(dumps(r) + "\n" for r in result.records))
    return result.records


@pytest.mark.parametrize("signum,status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_replay_serves_until_a_signal_stops_it_cleanly(tmp_path, signum, status):
    from tests.harness import Proc

    journal = tmp_path / "crash.journal"
    write_journal(journal, WALL, {"D01": (0, 0, 0)}, {"D01": "v1"}, ["D01=4,0,0"])
    proc = Proc("GCS", [sys.executable, "-m", "dronesim", "gcs", "--web", "127.0.0.1:0", "--replay", str(journal)],
                tmp_path)
    proc.expect(r"^web ground station: http")
    proc.p.send_signal(signum)
    assert proc.wait() == status, proc.text
    proc.expect(rf"stopped by {signal.Signals(signum).name}")
    assert "Traceback" not in proc.text


def test_replay_frames_follow_the_journal(tmp_path):
    journal = tmp_path / "crash.journal"
    records = write_journal(journal, WALL, {"D01": (0, 0, 0), "D02": (0, 3, 1)}, {"D01": "v1", "D02": "dstar"},
                            ["D01=4,0,0", "D02=0,4,1"])
    r = Replay(journal)
    turns = [x for x in records if x["record"] == "turn"]
    assert len(r.frames) == len(turns) + 1 and r.frames[0]["turn"] == 0
    assert [d["pos"] for d in r.frames[0]["drones"]] == [[0, 0, 0], [0, 3, 1]]
    last = {d["id"]: d for d in r.frames[-1]["drones"]}
    assert last["D01"]["status"] == "dead" and last["D01"]["cause"] == "building"
    assert last["D01"]["pos"] == [2, 0, 0]
    events = [e["text"] for f in r.frames for e in f["events"]]
    assert "D01 died at (2, 0, 0): crashed into a building" in events
    assert "target of D01 set to (4, 0, 0)" in events
    assert any(t.startswith("GAME OVER at turn") for t in events)
    data = r.replay_json()
    assert data["over"] == {"turn": records[-1]["turn"], "reason": records[-1]["reason"], "text": records[-1]["text"]}
    assert r.world_json()["mode"] == "replay" and r.world_json()["floors"][0][2] == "#####"
    json.dumps(data)


def test_replay_shows_reached_and_a_quit(tmp_path):
    journal = tmp_path / "quit.journal"
    write_journal(journal, WALL, {"D01": (0, 0, 1)}, {"D01": "dstar"}, ["D01=0,2,1"], quit_at=5)
    r = Replay(journal)
    assert r.frames[-1]["drones"][0]["status"] == "reached"
    texts = [e["text"] for f in r.frames for e in f["events"]]
    assert "D01 reached its target (0, 2, 1)" in texts
    assert "the ground station ended the game" in texts
    assert r.over["reason"] == "GCS_QUIT"


@pytest.mark.parametrize("content,message", [
    ("", "empty"),
    ('{"record": "turn", "turn": 1}\n', "not a dronesim journal"),
    ("not json\nnot json either\n", "not a journal record"),
])
def test_bad_journals_are_usage_errors(tmp_path, content, message):
    path = tmp_path / "bad.journal"
    path.write_text(content)
    with pytest.raises(UsageError, match=message):
        Replay(path)


# --------------------------------------------------------------------------- the HTTP server


class FakeBackend:
    mode = "live"

    def __init__(self) -> None:
        self.calls: list[tuple[str, dict]] = []
        self.fail: Exception | None = None

    def world(self) -> dict:
        return world_json(WALL, mode=self.mode)

    def replay(self) -> dict:
        raise Rejected("live", 404)

    def command(self, action: str, args: dict) -> dict:
        self.calls.append((action, args))
        if self.fail is not None:
            raise self.fail
        return {"ok": True, "text": f"{action} done"}


@pytest.fixture
def served():
    backend, hub = FakeBackend(), Hub()
    server = WebServer(("127.0.0.1", 0), backend, hub, LOG)
    server.start()
    try:
        yield server, backend, hub
    finally:
        server.stop(drain=2.0)


def call(server: WebServer, method: str, path: str, body: bytes | str | None = None, headers: dict | None = None):
    host, port = server.server_address[:2]
    conn = http.client.HTTPConnection(host, port, timeout=10)
    try:
        if isinstance(body, str):
            body = body.encode()
        hdrs = {"Content-Type": "application/json"} if body is not None else {}
        hdrs.update(headers or {})
        conn.request(method, path, body=body, headers=hdrs)
        resp = conn.getresponse()
        data = resp.read()
        return resp.status, resp.getheader("Content-Type") or "", data
    finally:
        conn.close()


def json_call(server, method, path, body=None, headers=None):
    code, ctype, data = call(server, method, path, body, headers)
    assert ctype.startswith("application/json"), (code, ctype, data)
    return code, json.loads(data)


def test_serves_the_page_and_its_assets(served):
    server, _, _ = served
    code, ctype, data = call(server, "GET", "/")
    assert code == 200 and ctype.startswith("text/html") and b'src="/app.js"' in data
    for path, kind in (("/app.js", "text/javascript"), ("/style.css", "text/css")):
        code, ctype, data = call(server, "GET", path)
        assert code == 200 and ctype.startswith(kind) and len(data) > 1000
    assert b"http" not in call(server, "GET", "/")[2].replace(b"http-equiv", b"")  # no CDN, nothing external
    assert server.url.startswith("http://127.0.0.1:")


def test_world_and_state(served):
    server, _, hub = served
    assert json_call(server, "GET", "/api/world")[1]["size"] == [5, 5, 2]
    code, body = json_call(server, "GET", "/api/state")
    assert code == 503 and "connecting" in body["error"]
    hub.publish({"seq": 1, "turn": 3})
    assert json_call(server, "GET", "/api/state?x=1") == (200, {"seq": 1, "turn": 3})
    assert json_call(server, "GET", "/api/replay")[0] == 404


def test_target_and_control_reach_the_backend(served):
    server, backend, _ = served
    assert json_call(server, "POST", "/api/target", '{"drone": "D01", "cell": [1, 2, 0]}') == \
        (200, {"ok": True, "text": "target done"})
    assert json_call(server, "POST", "/api/target", '{"drone": "D02", "cell": "3, 4, 1"}')[0] == 200
    assert json_call(server, "POST", "/api/control", '{"action": "pace", "value": 0.25}')[0] == 200
    assert json_call(server, "POST", "/api/control", '{"action": "quit"}')[0] == 200
    assert backend.calls == [("target", {"drone": "D01", "cell": (1, 2, 0)}),
                             ("target", {"drone": "D02", "cell": (3, 4, 1)}),
                             ("pace", {"value": 0.25}), ("quit", {"value": None})]


def test_refusals_of_the_backend_keep_their_status_and_message(served):
    server, backend, _ = served
    backend.fail = Rejected("(9, 0, 0) is outside the world: 0 <= x < 5", 422)
    assert json_call(server, "POST", "/api/target", '{"drone": "D01", "cell": [9, 0, 0]}') == \
        (422, {"error": "(9, 0, 0) is outside the world: 0 <= x < 5"})
    backend.fail = RuntimeError("a bug")
    code, body = json_call(server, "POST", "/api/target", '{"drone": "D01", "cell": [1, 0, 0]}')
    assert code == 500 and "internal error" in body["error"]
    backend.fail = None
    assert json_call(server, "POST", "/api/target", '{"drone": "D01", "cell": [1, 0, 0]}')[0] == 200  # still serving


@pytest.mark.parametrize("method,path,body,headers,code,fragment", [
    ("POST", "/api/target", "not json", None, 400, "not JSON"),
    ("POST", "/api/target", "\xff\xfe", None, 400, "not JSON"),
    ("POST", "/api/target", "[1, 2, 3]", None, 400, "JSON object"),
    ("POST", "/api/target", '{"drone": "D01"}', None, 400, '"cell"'),
    ("POST", "/api/target", '{"drone": 1, "cell": [1, 1, 1]}', None, 400, "drone must be a string"),
    ("POST", "/api/target", '{"drone": "D01", "cell": [1, 1]}', None, 400, "three integers"),
    ("POST", "/api/target", '{"drone": "D01", "cell": [1.5, 1, 0]}', None, 400, "three integers"),
    ("POST", "/api/target", '{"drone": "D01", "cell": "1,x,0"}', None, 400, "not x,y,z"),
    ("POST", "/api/target", '{"drone": "D01", "cell": [1, 1, 0], "turn": 3}', None, 400, "unknown fields"),
    ("POST", "/api/target", '{"drone": "D01", "cell": [' + "9" * 5000 + ", 1, 0]}", None, 400, "too many digits"),
    ("POST", "/api/target", '{"drone": "D01", "cell": "' + "9" * 5000 + ',1,0"}', None, 400, "not x,y,z"),
    ("POST", "/api/target", '{"drone": "D01", "cell": "\uff11,1,0"}', None, 400, "not x,y,z"),
    ("POST", "/api/target", '{"drone": "D01", "cell": ' + "[" * 5000 + "]" * 5000 + "}", None, 400, "nested too deep"),
    ("POST", "/api/control", '{"action": "pause"}', {"Origin": "http://[::1"}, 400, "bad Origin"),
    ("POST", "/api/control", '{"action": "explode"}', None, 400, "unknown action"),
    ("POST", "/api/control", '{}', None, 400, "unknown action"),
    ("POST", "/api/target", '{"drone": "D01", "cell": [1, 1, 0]}', {"Content-Type": "text/plain"}, 415, "JSON"),
    ("POST", "/api/target", '{"drone": "D01", "cell": [1, 1, 0]}', {"Origin": "http://elsewhere.test"}, 403,
     "cross-origin"),
    ("POST", "/api/target", "x" * 20000, None, 413, "larger than"),
    ("GET", "/api/target", None, None, 405, "use POST"),
    ("POST", "/api/world", "{}", None, 405, "use GET"),
    ("GET", "/etc/passwd", None, None, 404, "no such resource"),
    ("GET", "/../pyproject.toml", None, None, 404, "no such resource"),
    ("GET", "/static/app.js", None, None, 404, "no such resource"),
    ("DELETE", "/api/state", None, None, 405, "use GET"),
    ("BREW", "/", None, None, 501, "Unsupported method"),
])
def test_bad_http_input_gets_a_4xx_json_error(served, caplog, method, path, body, headers, code, fragment):
    server, backend, _ = served
    got, data = json_call(server, method, path, body, headers)
    assert got == code and fragment in data["error"], data
    assert backend.calls == []
    assert json_call(server, "GET", "/api/world")[0] == 200  # and the server goes on
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR or r.exc_info]  # no traceback


def test_missing_or_bad_content_length(served):
    server, _, _ = served
    for head, code in ((b"", 411), (b"Content-Length: banana\r\n", 400), (b"Content-Length: -5\r\n", 400)):
        with socket.create_connection(server.server_address[:2], timeout=10) as s:
            s.sendall(b"POST /api/target HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n" + head
                      + b"\r\n")
            reply = s.makefile("rb").read().decode()
        assert reply.startswith(f"HTTP/1.0 {code}"), reply
        assert json.loads(reply.split("\r\n\r\n", 1)[1])["error"]


def test_garbage_request_lines_get_json_errors(served):
    server, _, _ = served
    for raw in (b"\x16\x03\x01garbage\r\n\r\n", b"GET\r\n\r\n", b"GET / HTTP/9.9\r\n\r\n"):
        with socket.create_connection(server.server_address[:2], timeout=10) as s:
            s.sendall(raw)
            reply = s.makefile("rb").read().decode(errors="replace")
        assert re.match(r"HTTP/1\.[01] (400|505)", reply), reply
        assert "error" in json.loads(reply.split("\r\n\r\n", 1)[1])
    assert json_call(server, "GET", "/api/world")[0] == 200


class SSE:
    """A minimal EventSource: (event, data) pairs from a stream."""

    def __init__(self, server: WebServer) -> None:
        host, port = server.server_address[:2]
        self.conn = http.client.HTTPConnection(host, port, timeout=10)
        self.conn.request("GET", "/api/events")
        self.resp = self.conn.getresponse()
        assert self.resp.status == 200 and self.resp.getheader("Content-Type").startswith("text/event-stream")

    def next(self) -> tuple[str, dict]:
        event, data = "message", []
        while True:
            line = self.resp.fp.readline()
            if not line:
                raise EOFError("stream closed")
            line = line.decode().rstrip("\n")
            if not line:
                if data:
                    return event, json.loads("\n".join(data))
                event = "message"
                continue
            if line.startswith("event:"):
                event = line[6:].strip()
            elif line.startswith("data:"):
                data.append(line[5:].strip())

    def close(self) -> None:
        self.conn.close()


def test_events_send_the_full_state_at_once_then_every_change_then_end(served):
    server, _, hub = served
    hub.publish({"seq": 1})
    first = SSE(server)
    assert first.next() == ("state", {"seq": 1})  # a page that connects (or reconnects) gets it all at once
    hub.publish({"seq": 2})
    assert first.next() == ("state", {"seq": 2})
    second = SSE(server)
    assert second.next() == ("state", {"seq": 2})
    hub.publish({"seq": 3, "over": {"reason": "GCS_QUIT"}})
    closer = threading.Thread(target=hub.close, args=(10.0,))
    closer.start()
    for s in (first, second):
        assert s.next() == ("state", {"seq": 3, "over": {"reason": "GCS_QUIT"}})  # the final state is served
        assert s.next() == ("end", {})
        with pytest.raises(EOFError):
            s.next()
        s.close()
    closer.join()
    assert hub.subscribers == 0


def test_a_slow_page_gets_only_the_newest_state(served):
    server, _, hub = served
    hub.publish({"seq": 0})
    page = SSE(server)
    assert page.next()[1] == {"seq": 0}
    for n in range(1, 200):
        hub.publish({"seq": n})
    seen = []
    while not seen or seen[-1] != 199:
        seen.append(page.next()[1]["seq"])
    assert seen == sorted(seen) and seen[-1] == 199
    page.close()


def test_a_vanished_page_is_forgotten(served):
    server, _, hub = served
    hub.publish({"seq": 0})
    page = SSE(server)
    page.next()
    page.close()
    for n in range(50):  # writes to the closed socket fail; the handler unsubscribes
        hub.publish({"seq": n, "pad": "x" * 10000})
        if hub.subscribers == 0:
            break
    assert hub.close(10.0)


def raw(server: WebServer, request: bytes) -> bytes:
    """What the server answers to `request`, sent as it is, until it closes the connection."""
    with socket.create_connection(server.server_address[:2], timeout=10) as s:
        s.sendall(request)
        return s.makefile("rb").read()


def test_a_bad_absolute_url_gets_400(served, caplog):
    server, _, _ = served
    reply = raw(server, b"GET http://[::1/api/state HTTP/1.0\r\n\r\n").decode()
    assert reply.startswith("HTTP/1.0 400"), reply
    assert "bad request target" in json.loads(reply.split("\r\n\r\n", 1)[1])["error"]
    assert not [r for r in caplog.records if r.exc_info]


def test_a_client_that_hangs_up_before_its_error_is_no_traceback(served, caplog):
    server, _, _ = served
    ours, theirs = socket.socketpair()
    theirs.sendall(b"\x16\x03\x01 some bytes of a TLS hello")  # no end of line, then gone
    theirs.close()
    web_server._Handler(ours, ("127.0.0.1", 1), server)  # answers 400 to nobody: no BrokenPipeError out of it
    ours.close()
    assert server.rejects.snapshot() == {"http-400": 1}
    assert not [r for r in caplog.records if r.exc_info]


def test_a_broken_connection_is_routine_and_a_bug_is_logged(served, caplog):
    server, _, _ = served
    for exc in (ConnectionResetError(104, "reset"), RuntimeError("a bug")):
        try:
            raise exc
        except Exception:
            server.handle_error(None, ("127.0.0.1", 1))
    assert [(r.levelno, bool(r.exc_info)) for r in caplog.records if r.levelno >= logging.INFO] == \
        [(logging.ERROR, True)]


def test_a_burst_of_connections_waits_in_the_backlog():
    server = WebServer(("127.0.0.1", 0), FakeBackend(), Hub(), LOG)  # listening, not accepting yet
    try:
        burst = [socket.create_connection(server.server_address[:2], timeout=10) for _ in range(100)]
        for s in burst:  # (with socketserver's backlog of 5, the 7th connection timed out)
            s.close()
    finally:
        server.server_close()


def test_an_idle_or_half_sent_request_is_closed(served, monkeypatch):
    server, backend, _ = served
    monkeypatch.setattr(web_server._Handler, "timeout", 0.05)
    assert raw(server, b"") == b""  # connected, never a word
    assert raw(server, b"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\n") == b""  # headers never ended
    half_body = b"POST /api/control HTTP/1.0\r\nContent-Type: application/json\r\nContent-Length: 100\r\n\r\n{"
    assert raw(server, half_body) == b""
    assert server.rejects.snapshot() == {"timeout": 3} and backend.calls == []
    assert json_call(server, "GET", "/api/world")[0] == 200


def test_connections_beyond_the_cap_are_refused_at_once(served, monkeypatch):
    server, _, _ = served
    monkeypatch.setattr(web_server, "MAX_CONNECTIONS", 2)
    address = server.server_address[:2]
    held = [socket.create_connection(address, timeout=10) for _ in range(2)]
    for s in held:  # half-sent: each holds its place
        s.sendall(b"GET /api/world HTTP/1.0\r\n")
    reply = raw(server, b"").decode()  # accepted after them (in order): refused, not left waiting
    assert reply.startswith("HTTP/1.0 503"), reply
    assert "busy" in json.loads(reply.split("\r\n\r\n", 1)[1])["error"]
    assert server.rejects.snapshot() == {"busy": 1}
    for s in held:  # their requests end: their places are free
        s.sendall(b"\r\n")
        assert s.makefile("rb").read().startswith(b"HTTP/1.0 200")
        s.close()
    assert json_call(server, "GET", "/api/world")[0] == 200


def test_one_client_address_holds_at_most_its_share_of_the_connections(served, monkeypatch):
    """A host holding connections half-sent (slowloris) fills its own share (`PER_CLIENT`), not every place: another
    address is still served; its places come back as its requests end."""
    server, _, _ = served
    monkeypatch.setattr(web_server, "MAX_CONNECTIONS", 8)
    monkeypatch.setattr(web_server, "PER_CLIENT", 2)
    address = server.server_address[:2]
    held = [socket.create_connection(address, timeout=10) for _ in range(2)]
    for s in held:
        s.sendall(b"GET /api/world HTTP/1.0\r\n")
    reply = raw(server, b"").decode()  # a third from 127.0.0.1: refused at once
    assert reply.startswith("HTTP/1.0 503") and "from 127.0.0.1" in json.loads(reply.split("\r\n\r\n", 1)[1])["error"]
    with socket.create_connection(address, timeout=10, source_address=("127.0.0.2", 0)) as other:
        other.sendall(b"GET /api/world HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n")
        assert other.makefile("rb").read().startswith(b"HTTP/1.0 200")  # another address: served
    assert server.rejects.snapshot() == {"busy": 1}
    for s in held:
        s.sendall(b"\r\n")
        assert s.makefile("rb").read().startswith(b"HTTP/1.0 200")
        s.close()
    assert json_call(server, "GET", "/api/world")[0] == 200


def test_an_event_stream_outlives_the_idle_timeout(served, monkeypatch):
    server, _, hub = served
    monkeypatch.setattr(web_server._Handler, "timeout", 0.05)
    monkeypatch.setattr(web_server, "KEEPALIVE", 0.2)  # (nothing to send for longer than the timeout)
    hub.publish({"seq": 1})
    with socket.create_connection(server.server_address[:2], timeout=10) as s:
        s.sendall(b"GET /api/events HTTP/1.0\r\n\r\n")
        lines = s.makefile("rb")
        while lines.readline() != b": keepalive\n":
            pass
        while lines.readline() != b": keepalive\n":
            pass
        hub.publish({"seq": 2})
        while not (line := lines.readline()).startswith(b"data: "):
            pass
        assert json.loads(line[6:]) == {"seq": 2}


def test_a_stream_that_falls_behind_holds_only_the_newest_state():
    hub = Hub()
    stream = hub.subscribe()
    for n in range(1000):  # a page that reads nothing: one state held, not a thousand
        hub.publish({"seq": n})
    assert hub.next(stream, 0) == ('{"seq":999}', False)
    assert hub.next(stream, 0) == (None, False)
    hub.publish({"seq": 1000})
    threading.Thread(target=hub.close, args=(10.0,)).start()
    assert hub.next(stream, 10) == ('{"seq":1000}', True)  # the final state, then the end
    hub.unsubscribe(stream)


def test_a_page_that_stops_reading_is_dropped(served, monkeypatch):
    server, _, hub = served
    assert web_server._Handler.timeout == web_server.IDLE_TIMEOUT  # (a page is dropped after it; shortened here)
    monkeypatch.setattr(web_server._Handler, "timeout", 0.2)
    hub.publish({"pad": "x" * (16 << 20)})  # more than the kernel's buffers hold
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        s.settimeout(10)
        s.connect(server.server_address[:2])
        s.sendall(b"GET /api/events HTTP/1.0\r\n\r\n")
        head = b""
        while b"retry: 1000" not in head:  # subscribed; then it reads nothing more
            head += s.recv(1024)
        assert hub.close(10.0)  # its stream timed out writing, and ended
    assert hub.subscribers == 0 and server.rejects.snapshot() == {"timeout": 1}


def rebinding_post(server: WebServer, host: str):
    return json_call(server, "POST", "/api/control", '{"action": "pause"}', {"Host": host, "Origin": f"http://{host}"})


def test_a_foreign_host_is_refused_dns_rebinding(served):
    server, backend, _ = served
    port = server.server_address[1]
    for host in (f"attacker.example:{port}", "attacker.example", f"127.0.0.1.nip.io:{port}", f"localhost.evil:{port}"):
        code, body = rebinding_post(server, host)
        assert code == 403 and "not a name of this ground station" in body["error"], (host, body)
        assert json_call(server, "GET", "/api/state", headers={"Host": host})[0] == 403
    assert backend.calls == []
    assert server.rejects.snapshot() == {"http-403": 8}


@pytest.mark.parametrize("name", ["127.0.0.1", "[::1]", "localhost", "LocalHost.", "app.localhost", "192.0.2.7",
                                  "[2001:db8::7]", socket.gethostname()])
def test_the_page_opens_by_an_ip_address_localhost_or_this_machines_name(served, name):
    server, backend, _ = served
    host = f"{name}:{server.server_address[1]}"
    assert json_call(server, "GET", "/api/world", headers={"Host": host})[0] == 200
    assert rebinding_post(server, host)[0] == 200 and backend.calls == [("pause", {"value": None})]


def test_replay_backend_serves_frames_and_refuses_commands(tmp_path):
    journal = tmp_path / "r.journal"
    write_journal(journal, WALL, {"D01": (0, 0, 1)}, {"D01": "dstar"}, ["D01=0,2,1"])
    server = WebServer(("127.0.0.1", 0), web_node.ReplayBackend(Replay(journal)), Hub(), LOG)
    server.start()
    try:
        assert json_call(server, "GET", "/api/world")[1]["mode"] == "replay"
        assert json_call(server, "GET", "/api/replay")[1]["frames"][0]["turn"] == 0
        assert json_call(server, "POST", "/api/target", '{"drone": "D01", "cell": [1, 1, 1]}')[0] == 409
        assert json_call(server, "GET", "/api/state")[0] == 404
        assert json_call(server, "GET", "/api/events")[0] == 404
    finally:
        server.stop()


@pytest.mark.parametrize("text,address", [("8080", ("127.0.0.1", 8080)), ("0.0.0.0:80", ("0.0.0.0", 80)),
                                          ("localhost:0", ("localhost", 0)), ("[::1]:9000", ("::1", 9000)),
                                          (":7000", ("127.0.0.1", 7000))])
def test_parse_address(text, address):
    assert parse_address(text) == address


@pytest.mark.parametrize("text", ["http", "host:port", "70000", "-1", ""])
def test_parse_address_refuses(text):
    with pytest.raises(UsageError, match="--web"):
        parse_address(text)


def test_a_taken_port_is_a_usage_error(served):
    server, _, _ = served
    with pytest.raises(UsageError, match="cannot serve"):
        WebServer(server.server_address[:2], FakeBackend(), Hub(), LOG)


# --------------------------------------------------------------------------- the bridge to the main thread


def test_commands_cross_to_the_main_thread_and_back():
    q: queue.SimpleQueue = queue.SimpleQueue()
    backend = web_node.LiveBackend(q.put)
    state = started()

    def main_thread() -> None:
        for _ in range(2):
            web_node.carry_out(state, q.get(timeout=10))

    t = threading.Thread(target=main_thread)
    t.start()
    assert backend.command("target", {"drone": "D01", "cell": (1, 1, 0)})["ok"]
    with pytest.raises(Rejected, match="outside the world"):
        backend.command("target", {"drone": "D01", "cell": (9, 9, 9)})
    t.join()
    assert state.wanted == {"D01": (1, 1, 0)}
    backend.close()
    with pytest.raises(Rejected) as err:
        backend.command("step", {})
    assert err.value.status == 409


def test_a_main_thread_that_does_not_answer_gives_503(monkeypatch):
    monkeypatch.setattr(web_node, "COMMAND_TIMEOUT", 0.05)
    backend = web_node.LiveBackend(lambda cmd: None)
    with pytest.raises(Rejected) as err:
        backend.command("step", {})
    assert err.value.status == 503


# --------------------------------------------------------------------------- whole games over HTTP (no browser)


@pytest.mark.integration
def test_a_game_played_over_http_and_sse(tmp_path):
    from tests.harness import Cluster, embedded_router, journal_records

    with embedded_router() as locator, Cluster(locator, tmp_path) as c:
        journal = tmp_path / "web.journal"
        srv = c.start("SRV", "coordinator", "--seed", "7", "--journal", str(journal), "--admit-deadline", "60")
        srv.expect("coordinator ready")
        c.start("ENV", "env", "--no-draw")
        c.start("D01", "drone", "--id", "D01", "--autopilot", "dstar")
        gcs = c.start("GCS", "gcs", "--web", "127.0.0.1:0", "--pace", "0")
        url = re.search(r"web ground station: (http://\S+)", gcs.expect(r"web ground station: http")).group(1)
        host, port = url[len("http://"):].rstrip("/").split(":")
        server = type("S", (), {"server_address": (host, int(port))})()
        page = SSE(server)
        state = page.next()[1]
        while state["control"]["waiting"] != "target":
            state = page.next()[1]
        assert json_call(server, "POST", "/api/target", '{"drone": "D01", "cell": [10, 0, 0]}')[0] == 422
        assert json_call(server, "POST", "/api/target", '{"drone": "D02", "cell": [1, 0, 0]}')[0] == 422
        assert json_call(server, "POST", "/api/target", '{"drone": "D01", "cell": [9, 9, 0]}')[0] == 200
        while state["control"]["waiting"] != "idle":  # held: the drone is at its target
            state = page.next()[1]
        assert state["drones"][0]["pos"] == [9, 9, 0] and state["drones"][0]["status"] == "reached"
        turn = state["turn"]
        assert json_call(server, "POST", "/api/control", '{"action": "quit"}')[0] == 200
        while state["over"] is None:
            state = page.next()[1]
        assert state["over"]["reason"] == "GCS_QUIT" and state["turn"] == turn
        event = "state"
        while event == "state":  # the final state, then the end of the stream
            event, _ = page.next()
        assert event == "end"
        page.close()
        assert c.wait_all() == {"SRV": 0, "ENV": 0, "D01": 0, "GCS": 0}, [p.text for p in c.procs]
        assert "GAME OVER" in "\n".join(gcs.out)
        records = journal_records(journal)
        assert records[1]["targets"] == {"D01": [9, 9, 0]} and records[-1]["reason"] == "GCS_QUIT"


@pytest.mark.integration
def test_a_death_reaches_the_page_with_its_cause_and_the_ground_station_exits_0(tmp_path):
    from tests.harness import Cluster, embedded_router

    world = tmp_path / "wall.json"
    WALL.save(world)
    with embedded_router() as locator, Cluster(locator, tmp_path) as c:
        srv = c.start("SRV", "coordinator", "--world", str(world), "--admit-deadline", "60")
        srv.expect("coordinator ready")
        c.start("ENV", "env", "--no-draw")
        c.start("D01", "drone", "--id", "D01", "--autopilot", "v1")
        gcs = c.start("GCS", "gcs", "--web", "127.0.0.1:0", "--pace", "0", "--targets", "4,0,0")
        url = re.search(r"web ground station: (http://\S+)", gcs.expect(r"web ground station: http")).group(1)
        host, port = url[len("http://"):].rstrip("/").split(":")
        page = SSE(type("S", (), {"server_address": (host, int(port))})())
        event, state = page.next()
        while event == "state" and state["over"] is None:
            event, state = page.next()
        assert state["over"]["reason"] == "NO_DRONE_ALIVE"
        assert state["drones"][0]["status"] == "dead" and state["drones"][0]["cause"] == "building"
        assert "D01 died at (2, 0, 0): crashed into a building" in [e["text"] for e in state["log"]]
        page.close()
        assert set(c.wait_all().values()) == {0}, [p.text for p in c.procs]
