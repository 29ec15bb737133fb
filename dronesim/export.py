"""``dronesim export JOURNAL --mcap OUT.mcap``: a game as an MCAP file that opens in Foxglove and as a ROS 2 bag.

It holds the ROS 2 topics of ``dronesim ros2`` (docs/ros2.md: every drone's pose each turn, ``/tf``, the markers,
``/clock``, the trails every ``--path-every`` turns and at the end) and (unless ``--no-scene``) a Foxglove scene
(``/<namespace>/scene``, ``foxglove_msgs/msg/SceneUpdate``), every channel with its ``ros2msg`` schema and CDR
payloads: Foxglove shows the scene, rosbags and ``ros2 bag`` read every topic. Every message is logged at its
simulated time (turn x ``--turn-period``), so identical journals give byte-identical files. The journal is read line
by line: memory is bounded by the largest turn, not the game.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
from collections.abc import Iterator
from itertools import chain

import numpy as np

from coordinator.journal import header_config, is_turn, read
from entities.ros2.model import NAMESPACE, TURN_PERIOD_S, Scene, Snapshot
from schema import UsageError
from schema.errors import excerpt
from schema.tables import drone_number
from world.grid import CELL_SIZE_M, build_world

#: Bytes of messages in a chunk of the file (uncompressed). A chunk has a message index for each channel in it,
#: and a swarm's game has two channels a drone: 4 MiB chunks (foxglove-sdk's default is under 1 MiB) make the
#: 1000-drone benchmark's file 14 % smaller and its export about 10 % faster (BENCHMARKS.md, "MCAP export").
CHUNK = 4 << 20

#: Views of a drone (entities.ros2.model.VIEWS): alive, reached, dead, lost (a journal has no notes: "reached" is
#: standing on its target, as the web page's replay says).
ALIVE, REACHED, DEAD, LOST = 0, 1, 3, 4


def snapshots(records: Iterator[dict],
              drones: list[tuple[str, tuple[int, int, int]]]) -> Iterator[tuple[Snapshot | None, dict]]:
    """The `Snapshot` of the start (turn 0) and after each turn record, with the record (another record: None)."""
    index = {d: i for i, (d, _) in enumerate(drones)}
    numbers = np.array([drone_number(d) for d, _ in drones])
    pos = np.array([start for _, start in drones], np.int32).reshape(-1, 3)
    target = -np.ones_like(pos)
    state = np.zeros(len(drones), np.int8)

    def snap(turn: int) -> Snapshot:
        reached = (state == ALIVE) & (target[:, 0] >= 0) & (pos == target).all(axis=1)
        return Snapshot(turn=turn, numbers=numbers, pos=pos.copy(), view=np.where(reached, REACHED, state),
                        target=target.copy())

    yield snap(0), {}
    for r in records:
        if not is_turn(r):
            yield None, r
            continue
        for cells, into in ((r.get("targets"), target), (r.get("moves"), pos)):
            if cells:  # (a swarm's thousand cells in one assignment)
                rows = [index[d] for d in cells]
                into[rows] = np.fromiter(chain.from_iterable(cells.values()), np.int32, 3 * len(rows)).reshape(-1, 3)
        for d in r.get("deaths", {}):
            state[index[d]] = DEAD
        for d in r.get("lost", ()):
            state[index[d]] = LOST
        yield snap(r["turn"]), r


def export(journal: str, out: pathlib.Path, *, namespace: str = NAMESPACE, cell_size: float = CELL_SIZE_M,
           turn_period: float = TURN_PERIOD_S, path_every: int = 50, scene: bool = True,
           compression: str = "zstd") -> tuple[int, int]:
    """Write the MCAP file (without `scene`: only the ROS 2 topics); (turns, messages). A journal refused on the way
    (UsageError) leaves `out` as it was: the file is written beside it and takes its name once whole."""
    import foxglove
    from foxglove.mcap import MCAPCompression, MCAPWriteOptions

    from entities.ros2.foxglove import FoxgloveSink

    if path_every < 1:
        raise UsageError(f"--path-every must be >= 1, got {path_every}")
    records = read(journal)
    header = next(records, None)
    if header is None:
        raise UsageError(f"{journal} is empty: not a journal")
    config, _ = header_config(header)
    world = build_world(config.world, (d.start for d in config.drones))
    try:
        ros = Scene(namespace=namespace, cell_size=cell_size, turn_period=turn_period)
    except ValueError as err:
        raise UsageError(str(err)) from None
    context = foxglove.Context()
    turns = 0
    part = out.with_name(f".{out.name}.{os.getpid()}.part")  # (`out` replaced by a whole file only: `os.replace`)
    try:
        with foxglove.open_mcap(part, allow_overwrite=True, context=context,
                                writer_options=MCAPWriteOptions(profile="ros2", compression_threads=1, chunk_size=CHUNK,
                                                                compression={"zstd": MCAPCompression.Zstd,
                                                                             "lz4": MCAPCompression.Lz4,
                                                                             "none": None}[compression])):
            sink = FoxgloveSink(context, ros, with_scene=scene)
            sink.world(world.grid, ros.buildings(world.grid))
            last = None
            try:
                for snap, _ in snapshots(records, [(d.drone, d.start) for d in config.drones]):
                    if snap is None:
                        continue
                    sink.turn(snap, ros.turn(snap, paths=snap.turn % path_every == 0))
                    last, turns = snap, turns + 1
            except (KeyError, TypeError, ValueError, IndexError, OverflowError) as exc:
                raise UsageError(f"{journal}: bad journal record: {excerpt(repr(exc))}") from None
            if last is not None and len(paths := ros.paths(last.turn)):  # every trail as it ends
                sink.log(paths)
                sink.trails(last.turn)
        os.replace(part, out)
    finally:
        part.unlink(missing_ok=True)
    return turns, sink.logged


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="dronesim export", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("journal")
    p.add_argument("--mcap", required=True, metavar="OUT.mcap", help="the MCAP file to write (replaced if there)")
    p.add_argument("--namespace", default=NAMESPACE, help=f"prefix of the drones' topics (default {NAMESPACE})")
    p.add_argument("--cell-size", type=float, default=CELL_SIZE_M, help=f"metres a cell (default {CELL_SIZE_M})")
    p.add_argument("--turn-period", type=float, default=TURN_PERIOD_S,
                   help=f"simulated seconds a turn (default {TURN_PERIOD_S})")
    p.add_argument("--path-every", type=int, default=50, help="turns between two trails of a drone (default 50)")
    p.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd",
                   help="of the file's chunks (default zstd; none: about a third faster, files several times larger)")
    p.add_argument("--no-scene", action="store_true",
                   help="without the Foxglove scene (foxglove_msgs/msg/SceneUpdate): for a ROS 2 installation "
                        "without the foxglove_msgs package, or a smaller file")
    args = p.parse_args(argv)
    try:
        turns, messages = export(args.journal, pathlib.Path(args.mcap), namespace=args.namespace,
                                 cell_size=args.cell_size, turn_period=args.turn_period, path_every=args.path_every,
                                 scene=not args.no_scene, compression=args.compression)
    except UsageError as err:
        print(f"dronesim export: {err}", file=sys.stderr)
        return 2
    print(f"exported {turns} turns, {messages} ROS 2 messages and the Foxglove scene to {args.mcap}")
    return 0
