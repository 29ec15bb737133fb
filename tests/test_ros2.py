"""ROS 2 over Zenoh (entities/ros2, docs/ros2.md), tested against peers no one here wrote: rosbags decodes every
payload and computes every type hash; zenoh-ros2-sdk (a ROS-2-over-Zenoh client, given message definitions made
offline from rosbags' own) lists our topics with their types, decodes the poses, and sends a goal the drone flies to."""

from __future__ import annotations

import math
import re
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from coordinator.journal import header_config, tracks
from schema import UsageError
from schema.keys import RosKeys
from world.grid import World, build_world

rosbags = pytest.importorskip("rosbags", reason="rosbags is in the ros2 extra: pip install -e '.[ros2]'")

from entities.ros2.cdr import (  # noqa: E402
    dependencies,
    deserialize,
    make,
    own_msgdef,
    serialize,
    type_hash,
    typestore,
)
from entities.ros2.goals import Goal, Goals  # noqa: E402
from entities.ros2.model import CLOCK, MARKERS, PATH, POSE, TF, TYPES, Scene, Snapshot  # noqa: E402

from .harness import Cluster, Proc, embedded_router, journal_records  # noqa: E402


def snapshot(turn: int, pos: np.ndarray, view: np.ndarray | None = None, target: np.ndarray | None = None) -> Snapshot:
    n = len(pos)
    return Snapshot(turn=turn, numbers=np.arange(1, n + 1), pos=np.asarray(pos, np.int32),
                    view=np.zeros(n, np.int8) if view is None else view,
                    target=-np.ones((n, 3), np.int32) if target is None else target)


def test_every_message_is_what_rosbags_makes_of_the_turn() -> None:
    """Each turn's messages decode with rosbags to the drones' cells (x cell size), at turn x period."""
    scene = Scene(cell_size=2.0, turn_period=0.25)
    rng = np.random.default_rng(1)
    pos = rng.integers(0, 50, (37, 3))
    trails: dict[str, object] = {}
    for turn in range(1, 6):
        pos = pos + rng.integers(-1, 2, pos.shape)
        view = rng.integers(0, 5, len(pos)).astype(np.int8)
        target = np.where(rng.random((len(pos), 1)) < 0.5, pos + 3, -1)
        outs = scene.turn(snapshot(turn, pos, view, target))
        by_topic = {o.topic: o for o in outs}
        stamp = (turn // 4, (turn % 4) * 250_000_000)
        for i, name in enumerate(f"D{n:02d}" for n in range(1, len(pos) + 1)):
            msg = deserialize(by_topic[f"/dronesim/{name}/pose"].payload, POSE)
            assert (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id) == (*stamp, "map")
            p = msg.pose.position
            assert (p.x, p.y, p.z) == tuple(2.0 * pos[i]) and msg.pose.orientation.w == 1.0
            if (out := by_topic.get(f"/dronesim/{name}/path")) is not None:  # (sent when the drone moved)
                trails[name] = deserialize(out.payload, PATH)
            path = trails[name]
            assert [2.0 * pos[i][k] for k in range(3)] == [getattr(path.poses[-1].pose.position, a) for a in "xyz"]
        tf = deserialize(by_topic["/tf"].payload, TF)
        assert [t.child_frame_id for t in tf.transforms] == [f"D{n:02d}" for n in range(1, len(pos) + 1)]
        assert [[t.transform.translation.x, t.transform.translation.y, t.transform.translation.z]
                for t in tf.transforms] == (2.0 * pos).tolist()
        markers = deserialize(by_topic["/dronesim/markers"].payload, MARKERS).markers
        assert [m.ns for m in markers] == ["drones", "targets"]
        assert [[q.x, q.y, q.z] for q in markers[0].points] == (2.0 * pos).tolist()
        alpha = [c.a for c in markers[1].colors]
        assert [a > 0 for a in alpha] == (target[:, 0] >= 0).tolist()
        clock = deserialize(by_topic["/clock"].payload, CLOCK)
        assert (clock.clock.sec, clock.clock.nanosec) == stamp
        for o in outs:  # and each is byte for byte what rosbags serialises of what it decodes to
            assert serialize(deserialize(o.payload, o.typename), o.typename) == o.payload


def test_places_are_a_few_strided_runs_or_bytes() -> None:
    """A field's places: runs of alike steps written through a view each (a world's 300 000 cube centres: one run
    of groups of 3); places without a few such runs are written byte by byte."""
    from entities.ros2.cdr import Place

    cubes = (100 + 112 * np.arange(100_000)[:, None] + 8 * np.arange(3)).ravel()
    place = Place.of(cubes, 8)
    assert place.pieces is not None and [(p.rows, p.group, p.outer, p.inner) for p in place.pieces] == \
        [(100_000, 3, 112, 8)]
    names = np.concatenate([4 + 80 * np.arange(99), 4 + 80 * 99 + 88 * np.arange(900)])  # (two lengths of name)
    assert [(p.row, p.rows, p.outer) for p in Place.of(names, 4).pieces or ()] == [(0, 100, 80), (100, 899, 88)]
    scattered = np.cumsum(np.random.default_rng(2).integers(8, 40, 5_000)) * 8
    assert Place.of(scattered, 8).pieces is None


def test_drone_names_of_every_length_in_one_message() -> None:
    """Drones D01 to D1000 side by side (names of 3, 4 and 5 letters: a transform's place shifts with its name):
    every message, the Foxglove scene's too, is rosbags' own bytes for the cells given."""
    from entities.ros2.foxglove import SCENE, FoxScene

    numbers = np.array([1, 2, 98, 99, 100, 101, 102, 998, 999, 1000, 1001])
    rng = np.random.default_rng(5)
    scene = Scene(cell_size=0.5)
    fox = FoxScene(scene)
    for turn in (1, 2):
        pos = rng.integers(0, 40, (len(numbers), 3)).astype(np.int32)
        target = np.where(rng.random((len(numbers), 1)) < 0.5, pos + 1, -1).astype(np.int32)
        snap = Snapshot(turn=turn, numbers=numbers, pos=pos, view=rng.integers(0, 5, len(numbers)).astype(np.int8),
                        target=target)
        outs = list(scene.turn(snap)) + list(fox.turn(snap, scene.drones()))
        outs += list(fox.trails(turn, scene.sent_trails, scene.drones()))
        for o in outs:
            assert serialize(deserialize(o.payload, o.typename), o.typename) == o.payload, o.topic
        tf = deserialize(next(o for o in outs if o.topic == "/tf").payload, TF)
        assert [t.child_frame_id for t in tf.transforms] == [f"D{n:02d}" for n in numbers]
        assert [[t.transform.translation.x, t.transform.translation.y, t.transform.translation.z]
                for t in tf.transforms] == (0.5 * pos).tolist()
        entities = {e.id: e for o in outs if o.typename == SCENE for e in deserialize(o.payload, SCENE).entities}
        for i, n in enumerate(numbers):
            name = f"D{n:02d}"
            assert entities[f"trail/{name}"].lines[0].points[-1].x == 0.5 * pos[i][0]
            if turn == 1:
                assert entities[f"drone/{name}"].frame_id == name
                assert (f"target/{name}" in entities) == (target[i][0] >= 0)
            pose = deserialize(next(o for o in outs if o.topic == f"/dronesim/{name}/pose").payload, POSE)
            assert pose.pose.position.z == 0.5 * pos[i][2]


def test_trails_grow_with_moves_only() -> None:
    scene = Scene()
    pos = np.array([[1, 1, 1], [5, 5, 5]])
    scene.turn(snapshot(1, pos))
    outs = scene.turn(snapshot(2, pos + [[1, 0, 0], [0, 0, 0]]))
    paths = {o.topic: deserialize(o.payload, PATH) for o in outs if o.typename == PATH}
    assert list(paths) == ["/dronesim/D01/path"]  # D02 did not move: its trail is unchanged, not sent again
    assert [(q.pose.position.x, q.pose.position.y) for q in paths["/dronesim/D01/path"].poses] == [(1, 1), (2, 1)]


def test_a_trail_keeps_its_last_cells_oldest_first() -> None:
    from entities.ros2.model import Trails

    trails = Trails(2, limit=3)
    for step in range(5):  # D01 moves every time, D02 twice
        trails.add(np.array([0, 1]) if step in (1, 3) else np.array([0]),
                   np.array([[step, 0, 0], [0, step, 0]]) if step in (1, 3) else np.array([[step, 0, 0]]))
    groups = {k: (drones.tolist(), cells.tolist()) for k, drones, cells in trails.take()}
    assert groups == {3: ([0], [[[2, 0, 0], [3, 0, 0], [4, 0, 0]]]), 2: ([1], [[[0, 1, 0], [0, 3, 0]]])}
    assert trails.take() == []  # nothing moved since


def test_buildings_are_one_cube_list() -> None:
    grid = np.zeros((4, 4, 3), bool)
    grid[1, 2, 0] = grid[3, 3, 2] = True
    (out,) = Scene(cell_size=0.5).buildings(grid)
    markers = deserialize(out.payload, MARKERS).markers
    assert [(m.ns, m.type) for m in markers] == [("buildings", 6)]
    assert [(q.x, q.y, q.z) for q in markers[0].points] == [(0.5, 1.0, 0.0), (1.5, 1.5, 1.0)]
    assert serialize(deserialize(out.payload, MARKERS), MARKERS) == out.payload


def test_a_sequence_of_any_length_is_what_rosbags_serialises() -> None:
    """`Repeated` (a path's poses, a world's cubes) extrapolates rosbags' messages of 3 and 4 elements: for every
    length, byte for byte rosbags' own serialisation of what it decodes to, with the values given."""
    from entities.ros2.foxglove import SCENE, FoxScene
    from entities.ros2.model import building_markers, path_layout

    rng = np.random.default_rng(3)
    for k in (1, 2, 3, 5, 9, 64):
        xyz = rng.integers(-50, 50, (1, 3 * k)).astype(np.float64) / 4
        payload = path_layout(k).fill({"sec": [[7] * (k + 1)], "nsec": [[5] * (k + 1)], "xyz": xyz})[0].tobytes()
        path = deserialize(payload, PATH)
        assert [[q.pose.position.x, q.pose.position.y, q.pose.position.z] for q in path.poses] == \
            xyz.reshape(-1, 3).tolist()
        assert serialize(path, PATH) == payload
    for cells in (0, 1, 4, 11):
        grid = np.zeros((6, 6, 4), bool)
        grid.flat[rng.choice(grid.size, cells, replace=False)] = True
        payload = building_markers(grid, 0.25)
        assert [(q.x, q.y, q.z) for q in deserialize(payload, MARKERS).markers[0].points] == \
            [tuple(c) for c in (np.argwhere(grid) * 0.25).tolist()]
        assert serialize(deserialize(payload, MARKERS), MARKERS) == payload
        (update,) = FoxScene(Scene(cell_size=0.25)).buildings(grid)
        cubes = deserialize(update.payload, SCENE).entities[0].cubes
        assert [(c.pose.position.x, c.pose.position.y, c.pose.position.z) for c in cubes] == \
            [tuple(c) for c in (np.argwhere(grid) * 0.25).tolist()]
        assert serialize(deserialize(update.payload, SCENE), SCENE) == update.payload


def test_type_hashes_and_keys() -> None:
    """rmw_zenoh's key of a topic: domain, topic, DDS type name, RIHS01 hash (rosbags' own)."""
    keys = RosKeys(3)
    assert keys.topic("/dronesim/D01/pose", POSE, type_hash(POSE)) == (
        "3/dronesim/D01/pose/geometry_msgs::msg::dds_::PoseStamped_/" + typestore().hash_rihs01(POSE))
    assert type_hash(POSE).startswith("RIHS01_") and len(type_hash(POSE)) == 7 + 64
    token = keys.endpoint_token("abc", 0, 4, "MP", "/", "dronesim", "/tf", TF, type_hash(TF), "q")
    assert token == f"@ros2_lv/3/abc/0/4/MP/%/%/dronesim/%tf/tf2_msgs::msg::dds_::TFMessage_/{type_hash(TF)}/q"
    with pytest.raises(ValueError):
        RosKeys(-1)


def goal(x: float, y: float, z: float, frame: str = "map") -> bytes:
    return serialize(make(POSE, header=make("std_msgs/msg/Header", frame_id=frame),
                          pose=make("geometry_msgs/msg/Pose",
                                    position=make("geometry_msgs/msg/Point", x=x, y=y, z=z))), POSE)


def test_goals_refused_with_a_reason_and_counted() -> None:
    grid = np.zeros((6, 6, 4), bool)
    grid[2, 2, :2] = True
    goals = Goals(World.from_grid(grid), frozenset({"D01"}), cell_size=2.0)
    assert goals.read(Goal("D01", goal(6.2, 3.9, 2.0))) == ("D01", (3, 2, 1))
    bad = {"outside the world": goal(13.0, 0.0, 0.0), "in a building": goal(4.0, 4.0, 0.0),
           "other frame": goal(0.0, 0.0, 0.0, frame="odom"), "not finite": goal(math.nan, 0.0, 0.0),
           "malformed": b"\x00\x01\x00\x00garbage"}
    for reason, payload in bad.items():
        with pytest.raises(UsageError, match=reason):
            goals.read(Goal("D01", payload))
    with pytest.raises(UsageError, match="unknown drone"):
        goals.read(Goal("D07", goal(0.0, 0.0, 0.0)))
    assert goals.taken == 1 and sum(goals.refused.values()) == 6 and set(goals.refused) == {*bad, "unknown drone"}


def test_goals_beyond_a_float_in_cells_or_long_are_refused_in_short() -> None:
    """A finite goal whose cells are beyond a float (metres / a cell under 1 m) is outside the world, not a crash;
    a refusal's text is an excerpt, whatever the frame's or the numbers' length."""
    goals = Goals(World.from_grid(np.zeros((6, 6, 4), bool)), frozenset({"D01"}), cell_size=0.5)
    for payload in (goal(1.7976931348623157e308, 0.0, 0.0), goal(1e300, 0.0, 0.0), goal(0.0, 0.0, 0.0, "x" * 100_000)):
        with pytest.raises(UsageError, match="outside the world|other frame") as err:
            goals.read(Goal("D01", payload))
        assert len(str(err.value)) < 300
    assert goals.taken == 0 and goals.refused == {"outside the world": 2, "other frame": 1}


def status(turn: int, cells: list[tuple[int, int, int]]):
    from schema import DroneState, DroneStatus, Status

    return Status(turn=turn, sender="SRV", drones=tuple(
        DroneStatus(drone=f"D{i + 1:02d}", pos=c, state=DroneState.ALIVE) for i, c in enumerate(cells)))


def test_the_viewer_publishes_the_newest_turn_at_its_rate() -> None:
    """`dronesim ros2`'s core: it looks for the newest STATUS once a period (nothing read in between), publishes
    a turn once, and ends after OVER once the last turn went out."""
    import logging

    from entities.ros2.node import Viewer
    from network.transport import Received
    from schema import EndReason, Over

    class Sink:
        def __init__(self) -> None:
            self.turns: list[int] = []

        def world(self, grid: np.ndarray, outs: list) -> None:
            raise AssertionError("no map was given")

        def turn(self, snap: Snapshot, outs: list) -> None:
            self.turns.append(snap.turn)

    sink, asked = Sink(), []
    viewer = Viewer(Scene(), [sink], rate=10.0, logger=logging.getLogger("test"), cpu=lambda: 0.0)
    queue = {0.0: 1, 0.05: 2, 0.1: 3, 0.25: 3, 0.4: None}

    for now, turn in queue.items():
        def newest(turn: int | None = turn, now: float = now) -> Received | None:
            asked.append(now)
            return None if turn is None else Received("k", status(turn, [(1, 1, 1), (2, 2, 2)]))
        viewer.tick(now, newest)
    assert sink.turns == [1, 3] and asked == [0.0, 0.1, 0.25, 0.4]  # (0.05: not due; 0.25: turn 3 again)
    assert (viewer.published, viewer.skipped) == (2, 1), "turn 2 skipped: turn 3 had come when it looked"
    assert not viewer.ended(0.4)
    viewer.over, viewer.over_since = Over(turn=3, sender="SRV", reason=EndReason.TURN_LIMIT), 0.4
    assert viewer.ended(0.4)
    with pytest.raises(UsageError):
        Viewer(Scene(), [], rate=0.0, logger=logging.getLogger("test"))


def test_a_costly_turn_makes_the_viewer_wait() -> None:
    """A turn that cost the viewer C s of CPU: the next look C / ROS_CPU_SHARE s later, at most ROS_SLOWEST."""
    import logging

    from entities.ros2.node import Viewer
    from network.transport import Received
    from schema.tuning import ROS_CPU_SHARE, ROS_SLOWEST

    class Sink:
        def world(self, grid: np.ndarray, outs: list) -> None: ...
        def turn(self, snap: Snapshot, outs: list) -> None: ...

    spent = iter([0.0, 0.2 * ROS_CPU_SHARE, 1.0, 1.0 + 10 * ROS_SLOWEST])
    viewer = Viewer(Scene(), [Sink()], rate=20.0, logger=logging.getLogger("test"), cpu=lambda: next(spent))
    viewer.tick(0.0, lambda: Received("k", status(1, [(0, 0, 0)])))
    assert viewer.due == pytest.approx(0.2)
    viewer.tick(0.25, lambda: Received("k", status(2, [(0, 1, 0)])))
    assert viewer.due == pytest.approx(0.25 + ROS_SLOWEST)


def test_a_swarm_viewer_listens_only_while_a_turn_is_due() -> None:
    """`listen`: the STATUS subscription is declared when a turn is due (looked at a period later), kept while the
    viewer is due again within ROS_LISTEN_GAP (a cheap turn), dropped after a costly one until the next is due, and
    dropped while detached; OVER heard while not listening ends the viewer at once (the last STATUS went by)."""
    import logging

    from entities.ros2.node import Viewer, listen
    from network.transport import Newest, Received
    from schema import EndReason, Over
    from schema.tuning import ROS_CPU_SHARE, ROS_LISTEN_GAP

    class Sink:
        def world(self, grid: np.ndarray, outs: list) -> None: ...
        def turn(self, snap: Snapshot, outs: list) -> None: ...

    ring: list[Received | None] = []
    opened, closed = [], []

    def subscribe() -> Newest:
        opened.append(len(opened))
        ring.clear()
        return Newest(lambda: ring.pop() if ring else None, lambda: closed.append(len(opened)))

    clock = [0.0]
    viewer = Viewer(Scene(), [Sink()], rate=20.0, logger=logging.getLogger("test"), cpu=lambda: clock[0])
    sub = listen(viewer, None, 0.0, True, subscribe)
    assert sub is not None and opened == [0] and viewer.due == pytest.approx(0.05) and viewer.published == 0
    assert listen(viewer, sub, 0.01, True, subscribe) is sub  # not due yet
    ring.append(Received("k", status(1, [(0, 0, 0)])))
    assert listen(viewer, sub, 0.05, True, subscribe) is sub and viewer.published == 1  # cheap: due in a period
    assert viewer.due - 0.05 < ROS_LISTEN_GAP
    ring.append(Received("k", status(2, [(0, 1, 0)])))

    def costly() -> float:  # the turn's publishing costs 5 ms of CPU
        clock[0] += 0.005
        return clock[0]
    viewer.cpu = costly
    assert listen(viewer, sub, 0.1, True, subscribe) is None and viewer.published == 2 and closed == [1]
    assert viewer.due == pytest.approx(0.1 + 0.005 / ROS_CPU_SHARE, abs=0.01)  # (its own CPU, measured twice)
    assert listen(viewer, None, 0.2, True, subscribe) is None and opened == [0]  # not due: not listening
    sub = listen(viewer, None, viewer.due, True, subscribe)
    assert sub is not None and opened == [0, 1]
    assert listen(viewer, sub, viewer.due, False, subscribe) is None and closed == [1, 2]  # detached
    viewer.over, viewer.over_since = Over(turn=9, sender="SRV", reason=EndReason.TURN_LIMIT), 1.0
    viewer.missed_last = True  # (what the loop sets when OVER comes while not listening)
    assert viewer.ended(1.0)


# ------------------------------------------------------------------------------------------ against real peers


def write_msg_files(root: Path) -> Path:
    """The .msg files of every type we publish, made offline from rosbags' definitions (zenoh-ros2-sdk otherwise
    clones them from the internet at run time)."""
    for t in {d for typename in TYPES for d in dependencies(typename)}:
        path = root / f"{t}.msg"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(own_msgdef(t))
    return root


@pytest.fixture()
def sdk(tmp_path: Path):
    sdk = pytest.importorskip("zenoh_ros2_sdk", reason="zenoh-ros2-sdk is in the ros2 extra")
    import zenoh_ros2_sdk.message_registry as registry

    registry._registry = registry.MessageRegistry(str(write_msg_files(tmp_path / "msgs")))
    yield sdk
    if sdk.ZenohSession._instance is not None:
        sdk.ZenohSession._instance.close()
    registry._registry = None


def free_cell_above(world: World, start: tuple[int, int, int]) -> tuple[int, int, int]:
    x, y, _ = start
    for z in range(world.size[2] - 1, 0, -1):
        if not world.is_building((x, y, z)):
            return (x, y, z)
    raise AssertionError("no free cell above the start")


def two_drone_game(c: Cluster, journal: Path, max_turns: int, pace: float) -> None:
    """The coordinator of a 10x10x8 game of two seed drones (seed 7), its environment and drones, started."""
    srv = c.start("SRV", "coordinator", "--seed", "7", "--size", "10,10,8", "--drones", "2", "--max-turns",
                  str(max_turns), "--pace", str(pace), "--journal", str(journal), "--admit-deadline", "60")
    srv.expect("coordinator ready")
    c.start("ENV", "env", "--no-draw")
    for d in ("D01", "D02"):
        c.start(d, "drone", "--id", d, "--autopilot", "seed")


def test_live_topics_graph_and_goals_with_zenoh_ros2_sdk(tmp_path: Path, sdk) -> None:
    """A game with `dronesim ros2` and `dronesim gcs --ros2`: zenoh-ros2-sdk sees every topic with its type in
    its graph view, decodes the poses (each the journal's cell at its stamp's turn), and its goal flies D01
    there; bad goals are refused and counted; rosbags decodes every payload on the wire, under its type's hash."""
    journal = tmp_path / "game.journal"
    wire: list[tuple[str, bytes, bytes | None]] = []
    with embedded_router() as locator, Cluster(locator, tmp_path, log_level="INFO") as c:
        port = int(locator.rsplit(":", 1)[1])
        two_drone_game(c, journal, 300, 0.04)
        gcs = c.start("GCS", "gcs", "--ros2", "--quiet", "--no-draw")
        viewer = c.start("ROS2", "ros2", "--turn-period", "0.1")
        viewer.expect("ros2: node /dronesim")
        gcs.expect("taking ROS 2 goals")

        raw = zenoh.open(zenoh.Config.from_json5(f'{{mode: "client", connect: {{endpoints: ["{locator}"]}}}}'))
        lock = threading.Lock()

        def keep(sample: zenoh.Sample) -> None:
            att = sample.attachment.to_bytes() if sample.attachment is not None else None
            with lock:
                wire.append((str(sample.key_expr), sample.payload.to_bytes(), att))

        raw_sub = raw.declare_subscriber("0/**", keep)
        want = {"/dronesim/D01/pose": POSE, "/dronesim/D02/pose": POSE, "/dronesim/D01/path": PATH,
                "/tf": TF, "/dronesim/markers": MARKERS, "/clock": CLOCK}
        seen: dict[str, list[str]] = {}
        deadline = time.monotonic() + 30
        while not set(want) <= set(seen) and time.monotonic() < deadline:  # (each query waits 0.5 s)
            seen = dict(sdk.get_topic_names_and_types(router_port=port, timeout=0.5))
        assert {t: seen.get(t) for t in want} == {t: [ty] for t, ty in want.items()}, seen

        got: dict[str, list] = {t: [] for t in want}
        subs = [sdk.ROS2Subscriber(t, ty, got[t].append, router_port=port) for t, ty in want.items()]
        header = journal_records(journal)[0] if journal.exists() else None
        assert header is not None
        config, _ = header_config(header)
        world = build_world(config.world, (d.start for d in config.drones))
        start = dict((d.drone, d.start) for d in config.drones)["D01"]
        cell = free_cell_above(world, start)
        pub = sdk.ROS2Publisher("/dronesim/D01/goal_pose", POSE, router_port=port)
        deadline = time.monotonic() + 10  # the goal's route: the SDK's publisher matches the ground station's
        while not pub.pub.matching_status.matching and time.monotonic() < deadline:
            threading.Event().wait(0.05)
        for bad in ({"frame_id": "odom", "at": cell}, {"frame_id": "map", "at": (99, 0, 0)},
                    {"frame_id": "map", "at": (math.nan, 0, 0)}):
            publish(pub, bad["frame_id"], bad["at"])
        raw.put(f"0/dronesim/D01/goal_pose/geometry_msgs::msg::dds_::PoseStamped_/{type_hash(POSE)}", b"\x00\x01")
        publish(pub, "map", cell)
        gcs.expect(rf"ROS 2 goal: D01 -> \({cell[0]}, {cell[1]}, {cell[2]}\)")
        codes = c.wait_all(timeout=120)
        for s in subs:
            s.close()
        pub.close()
        raw_sub.undeclare()
        raw.close()
    assert set(codes.values()) == {0}, [p.text for p in c.procs if p.p.returncode]
    for reason in ("malformed", "other frame", "outside the world", "not finite"):  # (the process's log)
        gcs.expect(f"rejected /dronesim/D01/goal_pose: {reason}.*[(]{reason.replace(' ', '-')}[)]")

    records = journal_records(journal)
    final, _ = tracks(config, records)
    assert final["D01"].pos == cell  # the drone flew to the goal
    for topic in ("/dronesim/D01/pose", "/dronesim/D02/pose"):
        assert got[topic], topic
        drone = topic.split("/")[2]
        for msg in got[topic]:
            turn = round((msg.header.stamp.sec + msg.header.stamp.nanosec / 1e9) / 0.1)
            at, _ = tracks(config, records, until=turn)
            p = msg.pose.position
            assert (p.x, p.y, p.z) == at[drone].pos, (topic, turn)
    assert got["/dronesim/D01/pose"][-1].pose.position.x == cell[0]
    assert got["/tf"] and got["/clock"] and got["/dronesim/markers"] and got["/dronesim/D01/path"]

    # every sample we sent: the key's hash is rosbags' for the type named, the payload decodes, the attachment
    # is rmw_zenoh's (sequence number, timestamp, 16-byte publisher id)
    ours = [(k, p, a) for k, p, a in wire if "goal_pose" not in k]
    assert len(ours) > 50
    names = {RosKeys.dds_type(t): t for t in TYPES}
    sequences: dict[tuple[str, bytes], list[int]] = {}  # per publisher: a topic may have two (a latched one)
    for key, payload, att in ours:
        _, *topic, dds, hashed = key.split("/")
        typename = names[dds]
        assert hashed == typestore().hash_rihs01(typename), key
        deserialize(payload, typename)
        assert att is not None and len(att) == 33 and att[16] == 16, key
        sequences.setdefault((key, att[17:]), []).append(struct.unpack_from("<Q", att)[0])
    for (key, _), seq in sequences.items():
        assert seq == sorted(seq) and len(set(seq)) == len(seq), key


def test_the_web_ground_station_takes_ros2_goals_beside_its_page(tmp_path: Path) -> None:
    """`dronesim gcs --web ... --ros2`: a goal published on D01's goal topic is that drone's target as if clicked
    on the page (it shows it, in the drone's row and in its log), and the drone flies there; a goal in another
    frame is refused with a line in the page's log; the page's quit ends the game."""
    import json
    import urllib.request

    def api(url: str, path: str, body: dict | None = None) -> dict:
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(url + path, data=data, headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(req, timeout=10) as reply:
            return json.loads(reply.read())

    journal = tmp_path / "game.journal"
    with embedded_router() as locator, Cluster(locator, tmp_path, log_level="INFO") as c:
        two_drone_game(c, journal, 400, 0.02)
        gcs = c.start("GCS", "gcs", "--web", "127.0.0.1:0", "--pace", "0", "--ros2")
        found = re.search(r"(http://\S+)", gcs.expect("web ground station: http"))
        assert found is not None
        url = found.group(1).rstrip("/")
        gcs.expect("taking ROS 2 goals")
        config, _ = header_config(journal_records(journal)[0])
        world = build_world(config.world, (d.start for d in config.drones))
        cell = free_cell_above(world, dict((d.drone, d.start) for d in config.drones)["D01"])
        key = RosKeys(0).topic("/dronesim/D01/goal_pose", POSE, type_hash(POSE))
        raw = zenoh.open(zenoh.Config.from_json5(f'{{mode: "client", connect: {{endpoints: ["{locator}"]}}}}'))
        try:
            deadline = time.monotonic() + 30
            while True:  # (until the goal's route is up: the subscription is the ground station's to declare)
                raw.put(key, goal(*map(float, cell)))
                try:
                    gcs.expect(rf"ROS 2 goal: D01 -> \({cell[0]}, {cell[1]}, {cell[2]}\)", timeout=1)
                    break
                except AssertionError:
                    assert time.monotonic() < deadline, gcs.text()
            raw.put(key, goal(*map(float, cell), frame="odom"))
            gcs.expect("rejected /dronesim/D01/goal_pose: other frame")
        finally:
            raw.close()
        deadline = time.monotonic() + 60
        while (state := api(url, "/api/state")) and time.monotonic() < deadline:
            d01 = next(d for d in state["drones"] if d["id"] == "D01")
            if d01["pos"] == list(cell):
                break
            threading.Event().wait(0.2)
        assert d01["wanted"] == list(cell) and d01["pos"] == list(cell), state
        log = [e["text"] for e in state["log"]]
        assert f"ROS 2 goal: D01 -> {cell}" in log and any(t.startswith("refused a ROS 2 goal for D01: other frame")
                                                             for t in log), log
        assert api(url, "/api/control", {"action": "quit"})["ok"]
        codes = c.wait_all(timeout=120)
    assert set(codes.values()) == {0}, [p.text() for p in c.procs if p.p.returncode]
    records = journal_records(journal)
    final, _ = tracks(config, records)
    assert final["D01"].pos == cell and final["D01"].target == cell


def goal_route(pub) -> None:
    """Until zenoh-ros2-sdk's goal publisher matches the ground station's subscription (up to 30 s)."""
    deadline = time.monotonic() + 30
    while not pub.pub.matching_status.matching:
        assert time.monotonic() < deadline, "the ground station's goal subscription never matched"
        threading.Event().wait(0.05)


def enter_until_there(console: Proc, drone: str, cell: tuple[int, int, int], turns: int = 80) -> None:
    """Press Enter at the console, a turn each, until its status shows `drone` at `cell`; then q. (A status line seen
    late makes an Enter more: it answers a later turn, the drone hovering at its target.)"""
    assert console.p.stdin is not None
    at = f"  {drone} at ({cell[0]}, {cell[1]}, {cell[2]}):"
    for _ in range(turns):
        console.p.stdin.write("\n")
        console.p.stdin.flush()
        if console.expect(rf"^  {drone} at \(", fresh=True).startswith(at):
            break
    else:
        raise AssertionError(f"{drone} never reached {cell}:\n{console.text}")
    console.p.stdin.write("q\n")
    console.p.stdin.close()


def shown(console: Proc, text: str) -> bool:
    """Whether the console showed `text` at the start of a line of its own (its prompt goes on below)."""
    return any(line.startswith(text) for line in console.out)


def test_the_console_takes_ros2_goals_as_targets_typed_there(tmp_path: Path, sdk) -> None:
    """`dronesim gcs --ros2` with a person at the console (its input a pipe): zenoh-ros2-sdk's goal for D01 is a
    target typed at the console: it answers the turn the console holds (the game waits for it), the console shows
    it, and a goal in another frame refused with its reason; a line typed gives D02 its target (D02 hovered
    without one until then); the drones fly there one Enter a turn; q ends the game. The journal shows the flight."""
    journal = tmp_path / "game.journal"
    with embedded_router() as locator, Cluster(locator, tmp_path, log_level="INFO") as c:
        two_drone_game(c, journal, 300, 0.0)
        gcs = c.start("GCS", "gcs", "--ros2", "--no-draw", stdin=subprocess.PIPE)
        gcs.expect("taking ROS 2 goals")
        gcs.expect(r"^turn 0:")  # the game has begun (its header is in the journal)
        config, _ = header_config(journal_records(journal)[0])
        world = build_world(config.world, (d.start for d in config.drones))
        start = dict((d.drone, d.start) for d in config.drones)
        cell, other = free_cell_above(world, start["D01"]), free_cell_above(world, start["D02"])
        pub = sdk.ROS2Publisher("/dronesim/D01/goal_pose", POSE, router_port=int(locator.rsplit(":", 1)[1]))
        goal_route(pub)
        publish(pub, "odom", cell)
        gcs.expect("refused a ROS 2 goal for D01: other frame")
        publish(pub, "map", cell)
        gcs.expect(rf"ROS 2 goal: D01 -> \({cell[0]}, {cell[1]}, {cell[2]}\)")
        assert gcs.p.stdin is not None
        gcs.p.stdin.write(f"D02 {other[0]},{other[1]},{other[2]}\n")
        enter_until_there(gcs, "D01", cell)
        codes = c.wait_all(timeout=120)
        pub.close()
    assert set(codes.values()) == {0}, [p.text for p in c.procs if p.p.returncode]
    assert shown(gcs, "ROS 2 goals on /dronesim/<Dnn>/goal_pose (domain 0) are targets typed here")
    assert shown(gcs, f"ROS 2 goal: D01 -> {cell}") and shown(gcs, "refused a ROS 2 goal for D01: other frame")
    assert "turn 1: without a target, hovering: D01, D02; new target" in gcs.out[gcs.out.index("turn 0:") + 3], \
        gcs.text  # (the prompt that waited for the goal; the refusal's line ended it, and it was shown again)
    records = journal_records(journal)
    assert records[-1]["reason"] == "GCS_QUIT"
    final, _ = tracks(config, records)
    assert final["D01"].pos == cell and final["D01"].target == cell  # flown there
    assert final["D02"].target == other
    first, _ = tracks(config, records, until=1)
    assert first["D01"].target == cell and first["D02"].target is None  # the goal answered turn 1


def test_up_with_ros2_is_the_console_with_ros2_goals(tmp_path: Path, sdk) -> None:
    """`dronesim up --ros2` offers its console (the terminal's input goes to the ground station) beside ROS 2 goals:
    zenoh-ros2-sdk's goal flies D01 there, Enter a turn; q ends the game; every process exits 0."""
    journal = tmp_path / "up.journal"
    up = Proc("UP", [sys.executable, "-m", "dronesim", "up", "--insecure", "--ros2", "--seed", "7", "--size",
                     "10,10,8", "--max-turns", "200", "--journal", str(journal)], tmp_path, stdin=subprocess.PIPE)
    try:
        found = re.search(r"router on tcp/[\d.]+:(\d+),", up.expect("dronesim up: router on"))
        assert found is not None
        up.expect(r"^ROS 2 goals on /dronesim/<Dnn>/goal_pose \(domain 0\) are targets typed here")
        up.expect(r"^turn 0:")  # the game has begun (its header is in the journal)
        config, _ = header_config(journal_records(journal)[0])
        world = build_world(config.world, (d.start for d in config.drones))
        cell = free_cell_above(world, config.drones[0].start)
        pub = sdk.ROS2Publisher("/dronesim/D01/goal_pose", POSE, router_port=int(found.group(1)))
        goal_route(pub)
        publish(pub, "map", cell)
        up.expect(rf"^ROS 2 goal: D01 -> \({cell[0]}, {cell[1]}, {cell[2]}\)")
        enter_until_there(up, "D01", cell)
        assert up.wait(120) == 0, up.text
        pub.close()
    finally:
        up.kill()
    assert "dronesim up: all 5 processes exited 0" in up.out, up.text
    final, _ = tracks(config, journal_records(journal))
    assert final["D01"].pos == cell


def test_ros2_goals_are_not_taken_where_no_one_would_use_them(caplog: pytest.LogCaptureFixture) -> None:
    """A MAVLink ground station (its targets are its vehicles') and a replay refuse --ros2, rather than ignore it."""
    from entities.gcs_node import cli

    for face in (["--mavlink"], ["--web", "127.0.0.1:0", "--replay", "x.journal"]):
        assert cli([*face, "--ros2", "--connect", "tcp/127.0.0.1:1"]) == 2
    assert caplog.text.count("--ros2 goals go to the terminal or web ground station") == 2
    from dronesim.up import cli as up

    assert up(["--drones", "2", "--ros2", "--mavlink"]) == 2


def test_a_stuck_subscriber_neither_holds_our_publisher_nor_starves_another(tmp_path: Path) -> None:
    """A slow or absent ROS 2 subscriber never slows the game: the viewer is a process of its own (it reads the
    newest STATUS when it wants, a ring of one), and its telemetry (`RosGraph.publish`, best effort, congestion
    control DROP) beside a subscriber that stops reading after its first sample goes on: 128 MiB more of poses
    go out without waiting for it, and a subscriber that reads still gets what comes after."""
    from entities.ros2.model import Out
    from entities.ros2.node import RosGraph

    release = threading.Event()
    stuck_calls: list[int] = []
    got: list[int] = []
    topic = "/dronesim/D01/pose"

    def client() -> zenoh.Session:
        return zenoh.open(zenoh.Config.from_json5(f'{{mode: "client", connect: {{endpoints: ["{locator}"]}}}}'))

    with embedded_router() as locator:
        ours, stuck, reader = client(), client(), client()
        try:
            key = RosKeys(0).topic(topic, POSE, type_hash(POSE))
            stuck.declare_subscriber(key, lambda sample: (stuck_calls.append(1), release.wait()))
            reader.declare_subscriber(key, lambda sample: got.append(int.from_bytes(sample.payload.to_bytes()[:4],
                                                                                     "little")))
            graph = RosGraph(ours, RosKeys(0), "dronesim")
            filler = bytes(64 << 10)
            deadline = time.monotonic() + 30
            while not got and time.monotonic() < deadline:  # (until both subscriptions reach our publisher)
                graph.publish(Out(topic, POSE, (0).to_bytes(4, "little") + filler, 0))
                threading.Event().wait(0.05)
            assert got and stuck_calls == [1]
            for i in range(1, 2049):  # 128 MiB: far more than the stuck one's socket buffers and queues hold
                graph.publish(Out(topic, POSE, i.to_bytes(4, "little") + filler, i))
            deadline = time.monotonic() + 30
            while 10_000 not in got and time.monotonic() < deadline:  # what comes after the flood still comes
                graph.publish(Out(topic, POSE, (10_000).to_bytes(4, "little"), 0))
                threading.Event().wait(0.05)
            assert 10_000 in got and stuck_calls == [1]
            assert graph.sent >= 2049
            graph.close()
        finally:
            release.set()
            for session in (ours, stuck, reader):
                session.close()


def publish(pub, frame: str, at: tuple) -> None:
    x, y, z = (float(v) for v in at)
    Time, Header = (pub.session_mgr.store.types[t] for t in ("builtin_interfaces/msg/Time", "std_msgs/msg/Header"))
    Point, Quat, Pose = (pub.session_mgr.store.types[f"geometry_msgs/msg/{t}"] for t in ("Point", "Quaternion", "Pose"))
    pub.publish(header=Header(stamp=Time(sec=0, nanosec=0), frame_id=frame),
                pose=Pose(position=Point(x=x, y=y, z=z), orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0)))


# ------------------------------------------------------------------------------------------ MCAP export


@pytest.fixture(scope="module")
def game_journal(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 16-drone game (scenarios/swarm16.json) played in-process, as its journal."""
    import logging

    from coordinator.journal import dumps
    from dronesim.local import Inputs, simulate
    from dronesim.scenario import Scenario

    scenario = Scenario.load(str(Path(__file__).resolve().parent.parent / "scenarios" / "swarm16.json"))
    quiet = logging.getLogger("dronesim.tests.ros2")
    quiet.propagate = False
    result = simulate(scenario.game_config(), scenario.autopilots, Inputs(plan=scenario.plan()), quiet)
    path = tmp_path_factory.mktemp("export") / "swarm16.journal"
    path.write_text("".join(dumps(r) + "\n" for r in result.records), encoding="utf-8")
    return path


def journal_cells(journal: Path) -> tuple[dict[int, dict[str, tuple]], int]:
    records = journal_records(journal)
    config, _ = header_config(records[0])
    last = max(r["turn"] for r in records if r.get("record") == "turn")
    return {t: {d: tr.pos for d, tr in tracks(config, records, until=t)[0].items()} for t in range(last + 1)}, last


def test_export_mcap_reads_back_with_the_mcap_decoders(tmp_path: Path, game_journal: Path) -> None:
    """`dronesim export`: identical journals give byte-identical files; the mcap library's ROS 2 decoder decodes
    every message, the scene's too (foxglove_msgs/msg/SceneUpdate, the name Foxglove renders); the poses are the
    journal's cells, the scene has the buildings, drones, targets and trails."""
    pytest.importorskip("mcap_ros2", reason="mcap-ros2-support is in the ros2 extra")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory as Ros2Decoders

    from dronesim.export import main

    first, second = tmp_path / "a.mcap", tmp_path / "b.mcap"
    assert main([str(game_journal), "--mcap", str(first)]) == 0
    assert main([str(game_journal), "--mcap", str(second)]) == 0
    assert first.read_bytes() == second.read_bytes()

    cells, last = journal_cells(game_journal)
    topics: dict[str, int] = {}
    scene_ids: set[str] = set()
    with first.open("rb") as f:
        reader = make_reader(f, decoder_factories=[Ros2Decoders()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None
        assert {(s.encoding, c.message_encoding) for c in summary.channels.values()
                for s in [summary.schemas[c.schema_id]]} == {("ros2msg", "cdr")}
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            topics[channel.topic] = topics.get(channel.topic, 0) + 1
            if channel.topic == "/dronesim/scene":
                assert schema.name == "foxglove_msgs/msg/SceneUpdate"
                scene_ids |= {e.id for e in decoded.entities}
            elif channel.topic.endswith("/pose"):
                assert schema.name == POSE
                turn = round(message.log_time / 1e8)
                p = decoded.pose.position
                assert (p.x, p.y, p.z) == cells[turn][channel.topic.split("/")[2]]
    assert topics["/dronesim/D01/pose"] == last + 1 and topics["/tf"] == last + 1 and topics["/clock"] == last + 1
    assert {"/dronesim/markers", "/dronesim/D16/path", "/dronesim/scene"} <= set(topics)
    assert {"buildings", "drone/D01", "drone/D16", "trail/D16", "target/D01"} <= scene_ids


def test_export_is_a_ros2_bag_rosbags_reads_scene_and_all(tmp_path: Path, game_journal: Path) -> None:
    """The default export (with the Foxglove scene) opens with rosbags as a ROS 2 bag (rosbags 0.11 reads every
    schema as text of a ROS format: a protobuf scene made it fail), and its AnyReader decodes every message from
    the definitions in the file alone; the scene, applied update after update, ends as the game did: each drone a
    sphere in its own frame coloured by its state, each target a cube at the journal's target, each trail ending
    at the drone's last cell."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import Reader

    from dronesim.export import main
    from entities.ros2.model import COLOURS, VIEWS

    bag = tmp_path / "game.mcap"
    assert main([str(game_journal), "--mcap", str(bag), "--cell-size", "2.0"]) == 0
    with Reader(bag) as reader:
        assert {c.topic: c.msgtype for c in reader.connections}["/dronesim/scene"] == "foxglove_msgs/msg/SceneUpdate"
    entities: dict[str, object] = {}
    counts: dict[str, int] = {}
    with AnyReader([bag]) as reader:  # (its own type store: only what the file defines)
        for connection, _, data in reader.messages():
            msg = reader.deserialize(data, connection.msgtype)
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
            if connection.topic == "/dronesim/scene":
                for d in msg.deletions:
                    entities.pop(d.id)
                entities.update({e.id: e for e in msg.entities})
    assert counts["/dronesim/scene"] > 16 and counts["/dronesim/D01/pose"] == counts["/clock"]
    records = journal_records(game_journal)
    config, _ = header_config(records[0])
    final, _ = tracks(config, records)
    grid = build_world(config.world, (d.start for d in config.drones)).grid
    cubes = entities["buildings"].cubes  # type: ignore[attr-defined]
    assert [(c.pose.position.x, c.pose.position.y, c.pose.position.z) for c in cubes] == \
        [tuple(c) for c in (np.argwhere(grid) * 2.0).tolist()]
    for drone, track in final.items():
        sphere = entities[f"drone/{drone}"]
        assert (sphere.frame_id, sphere.frame_locked) == (drone, True)  # type: ignore[attr-defined]
        view = {"DEAD": "dead", "LOST": "lost"}.get(track.state, "reached" if track.pos == track.target else "alive")
        colour = sphere.spheres[0].color  # type: ignore[attr-defined]
        assert [colour.r, colour.g, colour.b, colour.a] == COLOURS[VIEWS.index(view)].astype(float).tolist()
        if track.target is not None:
            cube = entities[f"target/{drone}"].cubes[0]  # type: ignore[attr-defined]
            assert (cube.pose.position.x, cube.pose.position.y, cube.pose.position.z) == \
                tuple(2.0 * v for v in track.target)
        end = entities[f"trail/{drone}"].lines[0].points[-1]  # type: ignore[attr-defined]
        assert (end.x, end.y, end.z) == tuple(2.0 * v for v in track.pos)


def test_foxglove_msgs_are_foxglove_sdk_scene_field_for_field() -> None:
    """The ROS 2 scene's definitions (shipped as .msg text) have the fields, in order and of the same kinds, of
    the scene schema foxglove-sdk ships (protobuf, made from the same source as Foxglove's ROS 2 messages)."""
    pytest.importorskip("google.protobuf", reason="protobuf is in the ros2 extra")
    from foxglove.messages import SceneUpdate
    from google.protobuf import descriptor_pb2
    from google.protobuf.descriptor import FieldDescriptor as F

    from entities.ros2.foxglove import SCENE

    files = descriptor_pb2.FileDescriptorSet.FromString(bytes(SceneUpdate.get_schema().data))
    proto = {f"{file.package}.{m.name}": m for file in files.file for m in file.message_type}
    same = {".google.protobuf.Timestamp": "builtin_interfaces/msg/Time",
            ".google.protobuf.Duration": "builtin_interfaces/msg/Duration",
            ".foxglove.Pose": "geometry_msgs/msg/Pose", ".foxglove.Vector3": "geometry_msgs/msg/Vector3",
            ".foxglove.Point3": "geometry_msgs/msg/Point"}
    scalars = {F.TYPE_DOUBLE: "float64", F.TYPE_BOOL: "bool", F.TYPE_STRING: "string", F.TYPE_FIXED32: "uint32",
               F.TYPE_UINT32: "uint32", F.TYPE_ENUM: "uint8", F.TYPE_BYTES: "uint8[]"}
    checked = set()
    todo = [SCENE]
    while todo:
        ros = todo.pop()
        if ros in checked:
            continue
        checked.add(ros)
        mine = []
        for name, (kind, rest) in typestore().fielddefs[ros][1]:
            if kind.name == "BASE":
                mine.append((name, rest[0]))
            elif kind.name == "NAME":
                mine.append((name, rest))
            else:
                inner = rest[0][1] if rest[0][0].name == "NAME" else rest[0][1][0]
                mine.append((name, f"{inner}[]"))
        theirs = []
        for f in proto["foxglove." + ros.rsplit("/", 1)[1]].field:
            if f.type == F.TYPE_MESSAGE:
                kind = same.get(f.type_name, "foxglove_msgs/msg/" + f.type_name.rsplit(".", 1)[1])
            else:
                kind = scalars[f.type]
            theirs.append((f.name, kind + ("[]" if f.label == F.LABEL_REPEATED else "")))
        assert mine == theirs, ros
        todo += [k.rstrip("[]") for _, k in mine if k.startswith("foxglove_msgs/")]
    assert len(checked) == 13


def test_export_without_scene_is_a_bag_rosbags_reads(tmp_path: Path, game_journal: Path) -> None:
    from rosbags.rosbag2 import Reader

    from dronesim.export import main

    bag = tmp_path / "bag.mcap"
    assert main([str(game_journal), "--mcap", str(bag), "--no-scene", "--turn-period", "0.5"]) == 0
    cells, last = journal_cells(game_journal)
    seen: dict[str, int] = {}
    with Reader(bag) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types["/tf"] == TF and types["/dronesim/D03/pose"] == POSE and types["/dronesim/markers"] == MARKERS
        for connection, stamp, data in reader.messages():
            msg = deserialize(data, connection.msgtype)
            seen[connection.topic] = seen.get(connection.topic, 0) + 1
            if connection.msgtype == POSE:
                turn = round(stamp / 5e8)
                assert (msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec) == stamp
                p = msg.pose.position
                assert (p.x, p.y, p.z) == cells[turn][connection.topic.split("/")[2]]
    assert seen["/dronesim/D07/pose"] == last + 1


def test_export_refuses_what_is_not_a_journal(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from dronesim.export import main

    bad = tmp_path / "bad.journal"
    bad.write_text('{"record": "header", "format": "other"}\n')
    assert main([str(bad), "--mcap", str(tmp_path / "x.mcap")]) == 2
    assert "not a dronesim journal" in capsys.readouterr().err
    assert main([str(tmp_path / "missing"), "--mcap", str(tmp_path / "x.mcap")]) == 2


@pytest.mark.parametrize("record", ['{"record": "turn", "turn": 1, "moves": {"D01": [1099511627776, 0, 0]}}',
                                    '{"record": "turn", "turn": 10000000000000000000000000000000}',
                                    '{"record": "turn", "turn": 4611686018427387904}',
                                    '{"record": "turn", "turn": -3}'])
def test_export_refuses_a_bad_record_and_leaves_the_file_there(tmp_path: Path, game_journal: Path, record: str,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """A record out of range (a cell beyond int32, a turn beyond int64) is refused (exit 2, one line), and the MCAP
    file already at `--mcap` stays as it was: the export is written beside it, renamed once whole."""
    from dronesim.export import main

    out = tmp_path / "game.mcap"
    assert main([str(game_journal), "--mcap", str(out)]) == 0
    good = out.read_bytes()
    bad = tmp_path / "bad.journal"
    lines = game_journal.read_text().splitlines()
    bad.write_text("\n".join([*lines[:3], record]) + "\n")
    capsys.readouterr()
    assert main([str(bad), "--mcap", str(out)]) == 2
    err = capsys.readouterr().err
    assert "bad journal record" in err and "Traceback" not in err
    assert out.read_bytes() == good and sorted(p.name for p in tmp_path.iterdir()) == ["bad.journal", "game.mcap"]


# ------------------------------------------------------------------------------------------ Foxglove live


def test_foxglove_live_channels_over_websocket(tmp_path: Path) -> None:
    """`dronesim ros2 --foxglove`: a WebSocket client negotiating foxglove.sdk.v1 sees every channel advertised,
    subscribes, and decodes the poses (the journal's cells), /tf and the scene (foxglove_msgs/msg/SceneUpdate, CDR
    as every channel); the old subprotocol is refused."""
    ws = pytest.importorskip("websockets.sync.client", reason="websockets is in the ros2 extra")
    import json

    from websockets.exceptions import ConnectionClosed, InvalidStatus

    journal = tmp_path / "game.journal"
    with embedded_router() as locator, Cluster(locator, tmp_path, log_level="INFO") as c:
        viewer = c.start("ROS2", "ros2", "--foxglove", "127.0.0.1:0")
        two_drone_game(c, journal, 400, 0.05)  # (20 s: a loaded machine's viewer publishes a turn in seconds)
        c.start("GCS", "gcs", "--ros2", "--quiet", "--no-draw")  # (no target: the drones hover to the turn limit)
        url = viewer.expect(r"foxglove on ws://").rsplit(" ", 1)[1]  # (the server opens at the first turn)
        with pytest.raises(InvalidStatus):
            ws.connect(url, subprotocols=["foxglove.websocket.v1"], open_timeout=10).close()
        got: dict[str, list] = {}
        with ws.connect(url, subprotocols=["foxglove.sdk.v1"], open_timeout=10, max_size=None) as conn:
            assert conn.subprotocol == "foxglove.sdk.v1"
            channels: dict[int, dict] = {}
            subscribed: dict[int, dict] = {}
            want = {"/dronesim/D01/pose", "/tf", "/dronesim/scene", "/dronesim/markers"}
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and not (len(got.get("/dronesim/D01/pose", ())) > 5 and "/tf" in got
                                                       and {"buildings", "drone/D01", "drone/D02"} <= scene_ids(got)):
                try:
                    frame = conn.recv(timeout=5)
                except TimeoutError:
                    continue
                except ConnectionClosed:  # the game is over: the viewer has stopped its server
                    break
                if isinstance(frame, str):
                    msg = json.loads(frame)
                    if msg.get("op") == "advertise":
                        fresh = [ch for ch in msg["channels"] if ch["topic"] in want and ch["id"] not in channels]
                        channels.update({ch["id"]: ch for ch in fresh})
                        subs = [{"id": 100 + ch["id"], "channelId": ch["id"]} for ch in fresh]
                        subscribed.update({100 + ch["id"]: ch for ch in fresh})
                        if subs:
                            conn.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                    continue
                assert frame[0] == 1  # message data
                sub, log_time = struct.unpack_from("<IQ", frame, 1)
                ch = subscribed[sub]
                assert ch["encoding"] == "cdr" and ch["schemaEncoding"] == "ros2msg"
                decoded = deserialize(frame[13:], ch["schemaName"])
                got.setdefault(ch["topic"], []).append((log_time, decoded))
        codes = c.wait_all(timeout=120)
    assert set(codes.values()) == {0}, [p.text for p in c.procs if p.p.returncode]
    cells, _ = journal_cells(journal)
    assert len(got["/dronesim/D01/pose"]) > 5
    for log_time, msg in got["/dronesim/D01/pose"]:
        p = msg.pose.position
        assert (p.x, p.y, p.z) == cells[round(log_time / 1e8)]["D01"]
    assert [t.child_frame_id for t in got["/tf"][-1][1].transforms] == ["D01", "D02"]
    assert {"buildings", "drone/D01", "drone/D02"} <= scene_ids(got)


def scene_ids(got: dict[str, list]) -> set[str]:
    """The ids of the entities in the scene updates received so far."""
    return {e.id for _, update in got.get("/dronesim/scene", ()) for e in update.entities}


def test_the_shipped_rviz_config_names_our_topics_with_qos_they_match() -> None:
    """docs/dronesim.rviz (RViz2 itself is not run here: no ROS 2 package repository is reachable): fixed frame
    ``map``; each display's topic is one `dronesim ros2` publishes, of the type the display reads, asking a QoS our
    publisher offers (the markers reliable and transient local, as latched; telemetry best effort, volatile); the
    goal tool sends to the goal topic the ground station takes."""
    yaml = pytest.importorskip("yaml", reason="pyyaml is in the test extra")
    config = yaml.safe_load((Path(__file__).resolve().parent.parent / "docs" / "dronesim.rviz").read_text())
    manager = config["Visualization Manager"]
    assert manager["Global Options"]["Fixed Frame"] == "map"
    scene = Scene()
    reads = {"rviz_default_plugins/MarkerArray": (scene.markers_topic, ("Reliable", "Transient Local")),
             "rviz_default_plugins/Pose": (scene.pose_topic("D01"), ("Best Effort", "Volatile")),
             "rviz_default_plugins/Path": (scene.path_topic("D01"), ("Best Effort", "Volatile"))}
    shown = {}
    for display in manager["Displays"]:
        if "Topic" in display:
            topic = display["Topic"]
            shown[display["Class"]] = (topic["Value"], (topic["Reliability Policy"], topic["Durability Policy"]))
    assert shown == reads
    assert {t.get("Topic", {}).get("Value") for t in manager["Tools"]} >= {scene.goal_topic("D01")}


def test_up_runs_the_viewer_and_a_ground_station_taking_goals() -> None:
    from dronesim.up import build_parser, commands

    procs = dict(commands(build_parser().parse_args(["--drones", "2", "--ros2", "--foxglove", "8765"]),
                          "tcp/127.0.0.1:7447"))
    assert "--ros2" in procs["GCS"] and procs["ROS2"][3] == "ros2"
    assert procs["ROS2"][-2:] == ["--foxglove", "8765"]
    assert "ROS2" not in dict(commands(build_parser().parse_args(["--drones", "2"]), "tcp/127.0.0.1:7447"))
    web = dict(commands(build_parser().parse_args(["--drones", "2", "--ros2", "--web", "8080"]), "tcp/127.0.0.1:7447"))
    assert {"--ros2", "--web"} <= set(web["GCS"]) and "ROS2" in web  # (the page and ROS 2 goals, side by side)
