"""The pure world module: buildings, generation, files, queries, drawing, shortest paths."""

from __future__ import annotations

import json
from collections import deque

import numpy as np
import pytest

from schema import CellInfo, CellKind, UsageError
from world.grid import Building, World


def B(x: int, y: int, length: int, width: int, height: int) -> Building:
    return Building(x=x, y=y, length=length, width=width, height=height)


def check_world(world: World, keep_free=((0, 0, 0),)) -> None:
    """Invariants every generated world must satisfy."""
    nx, ny, nz = world.size
    assert world.grid.shape == world.size and world.grid.dtype == np.bool_
    assert not world.grid.flags.writeable
    expected = np.zeros(world.size, dtype=bool)
    for i, a in enumerate(world.buildings):
        assert a.fits_in(world.size)
        for b in world.buildings[i + 1:]:
            assert not a.intersects(b)
        expected[a.x:a.x + a.length, a.y:a.y + a.width, :a.height] = True
        for cell in keep_free:
            assert not a.is_inside(cell)
    assert np.array_equal(world.grid, expected)
    for cell in keep_free:
        assert not world.is_building(cell)


# --------------------------------------------------------------------------- Building


def test_building_is_inside() -> None:
    b = B(2, 3, 2, 1, 3)  # x 2..3, y 3, z 0..2
    assert b.is_inside((2, 3, 0)) and b.is_inside((3, 3, 2))
    assert not b.is_inside((4, 3, 0))  # past the length
    assert not b.is_inside((2, 4, 0))  # past the width
    assert not b.is_inside((2, 3, 3))  # above the roof
    assert not b.is_inside((1, 3, 0)) and not b.is_inside((2, 2, 0)) and not b.is_inside((2, 3, -1))


def test_building_intersects() -> None:
    a = B(0, 0, 2, 2, 3)
    assert a.intersects(B(1, 1, 2, 2, 1))  # overlapping corner
    assert B(1, 1, 2, 2, 1).intersects(a)
    assert a.intersects(B(0, 0, 1, 1, 9))  # contained, taller
    assert a.intersects(a)
    assert not a.intersects(B(2, 0, 1, 2, 3))  # touching along x
    assert not a.intersects(B(0, 2, 2, 1, 3))  # touching along y
    assert not a.intersects(B(2, 2, 1, 1, 3))  # touching at a corner
    assert not a.intersects(B(5, 5, 1, 1, 1))


@pytest.mark.parametrize("bad", [
    dict(x=-1, y=0, length=1, width=1, height=1),
    dict(x=0, y=0, length=0, width=1, height=1),
    dict(x=0, y=0, length=1, width=0, height=1),
    dict(x=0, y=0, length=1, width=1, height=0),
    dict(x=0.5, y=0, length=1, width=1, height=1),
    dict(x=True, y=0, length=1, width=1, height=1),
])
def test_building_validates(bad: dict) -> None:
    with pytest.raises(UsageError):
        Building(**bad)


def test_building_accepts_numpy_ints() -> None:
    b = Building(x=np.int64(1), y=np.int32(2), length=1, width=1, height=1)
    assert type(b.x) is int and b == B(1, 2, 1, 1, 1)


# --------------------------------------------------------------------------- generation


def test_generate_many_seeds_size_10() -> None:
    seen = set()
    for seed in range(300):
        world = World.generate((10, 10, 10), np.random.default_rng(seed))
        check_world(world)
        assert 1 <= len(world.buildings) <= 12
        seen.add(world.packed())
    assert len(seen) >= 295  # seeds give different worlds


@pytest.mark.parametrize("size", [(1, 1, 1), (3, 1, 2), (1, 5, 1), (2, 2, 1), (7, 3, 11), (64, 64, 16)])
def test_generate_odd_sizes(size) -> None:
    for seed in range(20):
        check_world(World.generate(size, np.random.default_rng(seed)))


def test_generate_size_1_is_empty() -> None:
    world = World.generate((1, 1, 1), np.random.default_rng(3))
    assert world.buildings == () and not world.grid.any()


def test_generate_is_deterministic() -> None:
    for seed in (0, 1, 12345):
        a = World.generate((20, 15, 8), np.random.default_rng(seed), count=30, max_footprint=4)
        b = World.generate((20, 15, 8), np.random.default_rng(seed), count=30, max_footprint=4)
        assert a == b and a.buildings == b.buildings and a.packed() == b.packed()
    assert World.generate() == World.generate((10, 10, 10), np.random.default_rng(0))
    assert World.generate(rng=7) == World.generate(rng=np.random.default_rng(7))


def test_generate_ignores_global_random_state() -> None:
    np.random.seed(1)
    a = World.generate((10, 10, 10), np.random.default_rng(5))
    np.random.seed(2)
    np.random.random(100)
    assert World.generate((10, 10, 10), np.random.default_rng(5)) == a


def test_generate_keep_free() -> None:
    starts = [(0, 0, 0), (5, 5, 0), (9, 9, 3), (2, 7, 6)]
    for seed in range(100):
        world = World.generate((10, 10, 10), np.random.default_rng(seed), count=40, keep_free=starts)
        check_world(world, starts)


def test_generate_keep_free_allows_buildings_below() -> None:
    # A start cell high up leaves room for short buildings under it.
    worlds = [World.generate((3, 3, 6), np.random.default_rng(s), count=9, max_footprint=1,
                             keep_free=[(1, 1, 5)]) for s in range(50)]
    for w in worlds:
        check_world(w, [(1, 1, 5)])
    assert any(w.is_building((1, 1, 0)) for w in worlds)


def test_generate_density_defaults() -> None:
    small = World.generate((10, 10, 10), np.random.default_rng(1))
    assert 3 <= len(small.buildings) <= 10
    assert max(max(b.length, b.width) for b in small.buildings) <= 3
    big = World.generate((64, 64, 16), np.random.default_rng(1))
    assert 150 <= len(big.buildings) <= 400
    assert all(b.height <= 16 for b in big.buildings)


def test_generate_crowded_returns_fewer() -> None:
    world = World.generate((4, 4, 2), np.random.default_rng(0), count=1000, max_footprint=2)
    check_world(world)
    assert 1 <= len(world.buildings) < 16


def test_generate_parameters() -> None:
    world = World.generate((30, 30, 20), np.random.default_rng(2), count=10, max_footprint=1, max_height=2)
    assert len(world.buildings) == 10
    assert all(b.length == b.width == 1 and b.height <= 2 for b in world.buildings)
    assert World.generate((10, 10, 10), np.random.default_rng(2), count=0).buildings == ()
    for bad in (dict(count=-1), dict(max_footprint=0), dict(max_height=0), dict(keep_free=[(10, 0, 0)]),
                dict(keep_free=[(0, 0)])):
        with pytest.raises(UsageError):
            World.generate((10, 10, 10), **bad)
    for size in ((0, 10, 10), (10, 10), (10, -1, 10)):
        with pytest.raises(UsageError):
            World.generate(size)


def test_generate_large_world() -> None:
    world = World.generate((256, 256, 32), np.random.default_rng(9))
    assert world.grid.shape == (256, 256, 32)
    assert len(world.buildings) > 2000
    assert not world.is_building((0, 0, 0))


# --------------------------------------------------------------------------- constructors


def test_from_buildings() -> None:
    world = World.from_buildings((4, 4, 3), [B(1, 1, 2, 1, 2), B(3, 0, 1, 4, 3)])
    assert world.is_building((1, 1, 0)) and world.is_building((2, 1, 1)) and not world.is_building((1, 1, 2))
    assert world.is_building((3, 3, 2))
    assert int(world.grid.sum()) == 2 * 2 + 4 * 3
    # touching buildings are fine
    World.from_buildings((4, 4, 3), [B(0, 0, 2, 2, 1), B(2, 0, 2, 2, 1), B(0, 2, 4, 2, 3)])


@pytest.mark.parametrize("buildings", [
    [B(0, 0, 2, 2, 1), B(1, 1, 2, 2, 1)],  # overlap
    [B(3, 0, 2, 1, 1)],  # past x
    [B(0, 3, 1, 2, 1)],  # past y
    [B(0, 0, 1, 1, 4)],  # through the ceiling
    [(0, 0, 1, 1, 1)],  # not a Building
])
def test_from_buildings_rejects(buildings) -> None:
    with pytest.raises(UsageError):
        World.from_buildings((4, 4, 3), buildings)


def test_from_grid_and_read_only() -> None:
    grid = np.zeros((3, 2, 2), dtype=bool)
    grid[1, 1, 1] = True  # an overhang: a building cell with nothing below
    world = World.from_grid(grid)
    assert world.size == (3, 2, 2) and world.buildings == ()
    assert world.is_building((1, 1, 1)) and not world.is_building((1, 1, 0))
    grid[0, 0, 0] = True  # the world kept its own copy
    assert not world.is_building((0, 0, 0))
    with pytest.raises(ValueError):
        world.grid[0, 0, 0] = True
    assert World.from_grid(np.array([[[0, 1]]])).is_building((0, 0, 1))
    for bad in (np.zeros((2, 2)), np.zeros((2, 0, 2), dtype=bool), np.full((1, 1, 1), 2), np.zeros((1, 1, 1))):
        with pytest.raises(UsageError):
            World.from_grid(bad)


def test_direct_construction_validates() -> None:
    grid = np.zeros((2, 2, 2), dtype=bool)
    World(size=(2, 2, 2), grid=grid)
    with pytest.raises(UsageError):
        World(size=(2, 2, 3), grid=grid)
    with pytest.raises(UsageError):
        World(size=(2, 2, 2), grid=grid, buildings=(B(0, 0, 1, 1, 1),))  # grid lacks the building


def test_equality_and_hash() -> None:
    a = World.from_buildings((3, 3, 3), [B(0, 0, 1, 1, 1)])
    b = World.from_buildings((3, 3, 3), [B(0, 0, 1, 1, 1)])
    raw = World.from_grid(a.grid)
    assert a == b and hash(a) == hash(b)
    assert a != raw  # same cells, but one knows its buildings
    assert np.array_equal(a.grid, raw.grid)


# --------------------------------------------------------------------------- files


def test_json_round_trip_buildings(tmp_path) -> None:
    world = World.generate((12, 9, 7), np.random.default_rng(4))
    data = world.to_json()
    assert data["format"] == "dronesim-world" and data["version"] == 1 and data["size"] == [12, 9, 7]
    assert data["buildings"] == [[b.x, b.y, b.length, b.width, b.height] for b in world.buildings]
    assert World.from_json(json.loads(json.dumps(data))) == world
    path = tmp_path / "w.json"
    world.save(path)
    assert json.loads(path.read_text()) == data
    assert World.load(path) == world
    assert World.load(str(path)) == world


def test_json_round_trip_cells(tmp_path) -> None:
    grid = np.zeros((3, 3, 3), dtype=bool)
    grid[1, :, 2] = True
    world = World.from_grid(grid)
    data = world.to_json()
    assert "buildings" not in data and data["cells"] == [[1, 0, 2], [1, 1, 2], [1, 2, 2]]
    world.save(tmp_path / "w.json")
    assert World.load(tmp_path / "w.json") == world
    empty = World.from_grid(np.zeros((2, 2, 2), dtype=bool))
    empty.save(tmp_path / "e.json")
    assert World.load(tmp_path / "e.json") == empty


GOOD = {"format": "dronesim-world", "version": 1, "size": [4, 4, 3], "buildings": [[0, 0, 2, 2, 1]]}


@pytest.mark.parametrize("patch, message", [
    ({"format": None}, "format"),
    ({"version": None}, "version"),
    ({"size": None}, "size"),
    ({"buildings": None}, "exactly one"),
    ({"format": "other"}, "format"),
    ({"version": 2}, "version"),
    ({"version": True}, "version"),
    ({"size": [4, 4]}, "size"),
    ({"size": [4, 4, "3"]}, "size"),
    ({"size": [4, 0, 3]}, "size"),
    ({"buildings": {"a": 1}}, "list"),
    ({"buildings": [[0, 0, 2, 2]]}, r"buildings\[0\]"),
    ({"buildings": [[0, 0, 2, 2, 1.5]]}, r"buildings\[0\]"),
    ({"buildings": [[0, 0, 2, 2, 0]]}, "height"),
    ({"buildings": [[3, 0, 2, 2, 1]]}, "does not fit"),
    ({"buildings": [[0, 0, 1, 1, 4]]}, "does not fit"),
    ({"buildings": [[0, 0, 2, 2, 1], [1, 1, 1, 1, 1]]}, "intersects"),
    ({"cells": [[0, 0, 0]]}, "exactly one"),
])
def test_from_json_rejects(patch: dict, message: str) -> None:
    data = dict(GOOD)
    for key, value in patch.items():
        if value is None:
            del data[key]
        else:
            data[key] = value
    with pytest.raises(UsageError, match=message):
        World.from_json(data)


@pytest.mark.parametrize("cells", [[[0, 0, 3]], [[0, 0]], [[-1, 0, 0]], "x"])
def test_from_json_rejects_bad_cells(cells) -> None:
    with pytest.raises(UsageError):
        World.from_json({"format": "dronesim-world", "version": 1, "size": [2, 2, 3], "cells": cells})


def test_load_rejects_bad_files(tmp_path) -> None:
    with pytest.raises(UsageError, match="cannot read"):
        World.load(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(UsageError, match="not valid JSON"):
        World.load(tmp_path / "bad.json")
    (tmp_path / "list.json").write_text("[1, 2]")
    with pytest.raises(UsageError, match="JSON object"):
        World.load(tmp_path / "list.json")
    (tmp_path / "x.json").write_text(json.dumps({**GOOD, "buildings": [[0, 0, 2, 2, 1], [1, 0, 1, 1, 1]]}))
    with pytest.raises(UsageError, match="x.json.*intersects"):
        World.load(tmp_path / "x.json")
    with pytest.raises(UsageError, match="cannot write"):
        World.from_json(GOOD).save(tmp_path / "no" / "such" / "dir.json")


# --------------------------------------------------------------------------- queries


def small_world() -> World:
    return World.from_buildings((3, 3, 2), [B(1, 1, 1, 1, 1)])


def test_contains_and_is_building() -> None:
    w = small_world()
    assert w.contains((0, 0, 0)) and w.contains((2, 2, 1))
    for c in ((-1, 0, 0), (3, 0, 0), (0, 3, 0), (0, 0, 2), (0, 0, -1)):
        assert not w.contains(c) and not w.is_building(c)
    assert w.is_building((1, 1, 0)) and not w.is_building((1, 1, 1))


def test_what_inside() -> None:
    w = small_world()
    occupants = {(0, 0, 0): ("D02", "D01"), (1, 1, 0): ("D03",), (5, 0, 0): ("D04",)}
    assert w.what_inside((0, 0, 1)) == CellInfo(pos=(0, 0, 1), kind=CellKind.EMPTY)
    assert w.what_inside((1, 1, 0)) == CellInfo(pos=(1, 1, 0), kind=CellKind.BUILDING)
    assert w.what_inside((-1, 0, 0)) == CellInfo(pos=(-1, 0, 0), kind=CellKind.OUTSIDE)
    assert w.what_inside((0, 0, 0), occupants) == CellInfo(pos=(0, 0, 0), kind=CellKind.EMPTY,
                                                           drones=("D01", "D02"))
    assert w.what_inside((1, 1, 0), occupants).drones == ("D03",)
    assert w.what_inside((5, 0, 0), occupants) == CellInfo(pos=(5, 0, 0), kind=CellKind.OUTSIDE,
                                                           drones=("D04",))
    info = w.what_inside((np.int64(2), 2, 1))
    assert info.pos == (2, 2, 1) and type(info.pos[0]) is int


def test_free_neighbours() -> None:
    w = small_world()
    assert w.free_neighbours((1, 0, 0)) == ((2, 0, 0), (0, 0, 0), (1, 0, 1))  # +y is the building
    assert w.free_neighbours((1, 1, 1)) == ((2, 1, 1), (0, 1, 1), (1, 2, 1), (1, 0, 1))
    assert w.free_neighbours((0, 0, 0)) == ((1, 0, 0), (0, 1, 0), (0, 0, 1))


def test_packed_round_trip() -> None:
    for size, seed in (((10, 10, 10), 1), ((3, 1, 2), 2), ((7, 5, 3), 3), ((1, 1, 1), 0)):
        world = World.generate(size, np.random.default_rng(seed))
        data = world.packed()
        n = size[0] * size[1] * size[2]
        assert len(data) == (n + 7) // 8
        assert data == np.packbits(world.grid.ravel(order="C")).tobytes()
        back = World.from_packed(size, data)
        assert np.array_equal(back.grid, world.grid) and back.buildings == ()
    with pytest.raises(UsageError):
        World.from_packed((10, 10, 10), b"\x00" * 3)


# --------------------------------------------------------------------------- drawing


def drawing_world() -> World:
    # size (2, 3, 2): a building on x = 1, y = 1..2, one floor high.
    return World.from_buildings((2, 3, 2), [B(1, 1, 1, 2, 1)])


def test_draw_full() -> None:
    text = drawing_world().draw({"D01": (0, 0, 0)}, targets={"D01": (0, 2, 1)}, trail=[(0, 1, 0), (0, 0, 0)])
    assert text == (
        "z = 0\n"
        "D01 +++ EPT\n"
        "EPT BLK BLK\n"
        "\n"
        "z = 1\n"
        "EPT EPT TGT\n"
        "EPT EPT EPT\n"
        "\n"
        "legend: EPT empty, BLK building, TGT target, +++ trail, Dnn drone, !!! several drones;"
        " row = x, column = y, (0,0) top-left"
    )


def test_draw_compact() -> None:
    text = drawing_world().draw({"D01": (0, 0, 0), "D02": (1, 0, 1), "D03": (1, 0, 1)},
                                targets={"D01": (0, 2, 1)}, trail=[(0, 1, 0)], compact=True)
    assert text == (
        "z = 0\n"
        "1*.\n"
        ".##\n"
        "\n"
        "z = 1\n"
        "..X\n"
        "!..\n"
        "\n"
        "legend: . empty, # building, X target, * trail, digit = drone (last character of its id),"
        " ! several drones; row = x, column = y, (0,0) top-left"
    )


def test_draw_options() -> None:
    w = drawing_world()
    only = w.draw(floors=[1])
    assert only.startswith("z = 1\nEPT EPT EPT\nEPT EPT EPT\n\nlegend:")
    assert "z = 0" not in only
    # several drones, long ids, drones outside the world are not drawn
    text = w.draw({"D01": (0, 0, 0), "D02": (0, 0, 0), "D100": (1, 0, 0), "D05": (9, 9, 9)}, floors=[0])
    assert text.splitlines()[1:3] == ["!!!  EPT  EPT", "D100 BLK  BLK"]
    with pytest.raises(UsageError):
        w.draw(floors=[2])
    # defaults: full for small worlds, compact past 16
    assert "EPT" in World.generate((16, 16, 1)).draw()
    big = World.generate((17, 4, 2)).draw()
    assert "EPT" not in big and big.splitlines()[1] in {"".join(r) for r in
                                                      np.where(World.generate((17, 4, 2)).grid[:, :, 0], "#", ".")}


# --------------------------------------------------------------------------- shortest paths


def wall_world(gap: bool) -> World:
    """5 x 5 x 2 with a wall at x = 2 through every y and z, with or without a one-cell gap."""
    grid = np.zeros((5, 5, 2), dtype=bool)
    grid[2, :, :] = True
    if gap:
        grid[2, 4, 1] = False
    return World.from_grid(grid)


def bfs_reference(world: World, start, goal):
    if world.is_building(start) or world.is_building(goal):
        return None
    dist = {start: 0}
    queue = deque([start])
    while queue:
        c = queue.popleft()
        if c == goal:
            return dist[c]
        for n in world.free_neighbours(c):
            if n not in dist:
                dist[n] = dist[c] + 1
                queue.append(n)
    return None


def test_shortest_path_wall() -> None:
    open_ = wall_world(gap=True)
    # (0,0,0) -> (0,4,0)=4 moves along y, up 1, +x twice through the gap... to (4,0,0)
    assert open_.shortest_path_length((0, 0, 0), (4, 0, 0)) == 4 + 1 + 4 + 1 + 4
    assert open_.shortest_path_length((0, 0, 0), (1, 3, 0)) == 4
    assert open_.shortest_path_length((0, 0, 0), (0, 0, 0)) == 0
    closed = wall_world(gap=False)
    assert closed.shortest_path_length((0, 0, 0), (4, 0, 0)) is None
    assert closed.shortest_path_length((0, 0, 0), (1, 4, 1)) == 6
    assert closed.shortest_path_length((0, 0, 0), (2, 0, 0)) is None  # building goal
    assert closed.shortest_path_length((2, 0, 0), (0, 0, 0)) is None  # building start
    assert closed.shortest_path_length((0, 0, 0), (5, 0, 0)) is None  # outside


def test_shortest_path_matches_reference() -> None:
    rng = np.random.default_rng(0)
    for seed in range(20):
        world = World.from_grid(np.random.default_rng(seed).random((6, 5, 4)) < 0.3)
        for _ in range(10):
            a = tuple(int(v) for v in rng.integers(0, (6, 5, 4)))
            b = tuple(int(v) for v in rng.integers(0, (6, 5, 4)))
            assert world.shortest_path_length(a, b) == bfs_reference(world, a, b)


def test_shortest_path_benchmark_size() -> None:
    world = World.generate((64, 64, 16), np.random.default_rng(3))
    d = world.shortest_path_length((0, 0, 0), (63, 63, 15))
    assert d is not None and d >= 63 + 63 + 15
