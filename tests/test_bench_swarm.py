"""`dronesim bench swarm` (benchmarks/swarm.py): a quick run writes its table, and its metrics are right."""

from __future__ import annotations

import pathlib

import numpy as np

from benchmarks import cli, swarm


def test_quick_run_writes_the_section(tmp_path: pathlib.Path) -> None:
    out = tmp_path / "BENCHMARKS.md"
    out.write_text("# Benchmarks\n\n## Other\n\nkept\n")
    assert cli(["swarm", "--quick", "--families", "empty-32-32", "--no-city", "--no-pogema", "--no-city-distributed",
                "--write", "--output", str(out)]) == 0
    text = out.read_text()
    assert "## Other\n\nkept" in text and swarm.SECTION in text
    rows = [line for line in text.splitlines() if line.startswith("| empty-32-32 |")]
    assert [r.split(" | ")[3] for r in rows] == ["fixed", "pibt", "pibt+map", "lacam"] * 2
    for r in rows:
        assert r.split(" | ")[1] == "0"  # no edge on no cycle: PIBT's condition holds
        if r.split(" | ")[3] != "fixed":
            assert r.split(" | ")[4:6] == ["1.00", "100.0 %"], r  # every agent arrives on an empty map


def test_quick_distributed_cities_play_and_keep_their_subsection(tmp_path: pathlib.Path) -> None:
    """`--city-distributed --quick`: a small city of LRTA* drones over two swarm hosts through real processes,
    played to its end without a collision, in a subsection that the MovingAI table's --write keeps."""
    out = tmp_path / "BENCHMARKS.md"
    out.write_text("# Benchmarks\n\n## Other\n\nkept\n")
    assert cli(["swarm", "--quick", "--city-distributed", "--city-runs", "1", "--no-pogema", "--write",
                "--output", str(out)]) == 0
    text = out.read_text()
    rows = [line.split(" | ") for line in text.splitlines() if line.startswith("| 16x16x4 |")]
    assert len(rows) == 1 and rows[0][1:4] == ["40", "2", "1"], rows
    assert rows[0][5] != "0" and rows[0][8] == "0"  # turns measured, no collision
    assert swarm.SECTION in text and swarm.CITY_SECTION in text
    assert cli(["swarm", "--quick", "--families", "empty-32-32", "--no-city", "--no-pogema", "--no-city-distributed",
                "--write", "--output", str(out)]) == 0
    again = out.read_text()
    assert "| empty-32-32 |" in again and swarm.CITY_SECTION in again and "| 16x16x4 | 40 | 2 | 1 |" in again
    assert again.index(swarm.SECTION) < again.index(swarm.CITY_SECTION) and "## Other\n\nkept" in again


def test_reachable_cells_are_one_component() -> None:
    grid = np.zeros((5, 4, 1), bool)
    grid[2, :, 0] = True  # a wall cutting the world in two
    reach = swarm.reachable(grid, (0, 0, 0))
    assert reach[:2].all() and not reach[2:].any()
    grid[2, 3, 0] = False  # a door
    assert swarm.reachable(grid, (0, 0, 0)).sum() == 5 * 4 - 3


def test_costs_follow_the_journal() -> None:
    starts = {"D01": (0, 0, 0), "D02": (5, 5, 0)}
    goals = {"D01": (1, 0, 0), "D02": (5, 5, 0)}
    records = [{"record": "header"},
               {"record": "turn", "turn": 1, "moves": {"D01": [1, 0, 0], "D02": [5, 6, 0]}},
               {"record": "turn", "turn": 2, "moves": {"D02": [5, 5, 0]}},
               {"record": "turn", "turn": 3}]
    costs, turns, collisions, at_256, last = swarm._costs(records, ["D01", "D02"], starts, goals)
    assert costs == [1, 2] and turns == 3 and collisions == 0  # D02 was pushed off its goal and came back
    assert at_256 == 2 and last == [1, 2]  # (a game shorter than 256 turns: its end counts)
    records.append({"record": "turn", "turn": 4, "moves": {"D01": [2, 0, 0]}, "deaths": {"D02": "VERTEX"}})
    assert swarm._costs(records, ["D01", "D02"], starts, goals) == ([None, None], 4, 1, 0, [4, 2])


def test_isr_at_256_and_the_turn_limit() -> None:
    """The ISR at turn 256 (POGEMA's episode) counts who was on its goal then, whatever came later; the turn
    limit on 32 x 32 is 4 x the lower-bound makespan, at least 256."""
    starts, goals = {"D01": (0, 0, 0)}, {"D01": (1, 0, 0)}
    records = [{"record": "turn", "turn": t, **({"moves": {"D01": [1, 0, 0]}} if t == 300 else {})}
               for t in range(1, 301)]
    assert swarm._costs(records, ["D01"], starts, goals) == ([300], 300, 0, 0, [300])
    maze = swarm.movingai_instance("maze-32-32-2", 10, 1)
    assert maze.max_turns == max(swarm.TURNS_32, swarm.LIMIT_PER_MAKESPAN * max(maze.optimal)) > swarm.TURNS_32


def test_lrta_alone_flies_the_city_trips(capsys) -> None:
    """`--lrta-alone --quick`: the small city's trips flown each alone, for cube radii 0-2: every trip home."""
    assert cli(["swarm", "--quick", "--lrta-alone"]) == 0
    rows = [line.split(" | ") for line in capsys.readouterr().out.splitlines() if line[:4] in ("| 0 ", "| 1 ", "| 2 ")]
    assert [r[0] for r in rows] == ["| 0", "| 1", "| 2"], rows
    for r in rows:
        assert r[1].isdigit() and r[3] == "0", r  # every trip home, none over the game's limit


def test_bridges_are_the_edges_on_no_cycle() -> None:
    ring = np.zeros((3, 3, 1), bool)
    ring[1, 1, 0] = True  # a ring of 8 cells round a building: every edge on a cycle
    assert swarm.bridges(~ring) == 0
    tail = np.ones((5, 3, 1), bool)
    tail[:3] = ring
    tail[3:, 1, 0] = False  # the ring and a tail of two cells hanging off it: its two edges lie on no cycle
    assert swarm.bridges(~tail) == 2
    assert swarm.bridges(np.ones((1, 4, 1), bool)) == 3  # a corridor: every edge
    two = np.zeros((2, 2, 2), bool)  # a 2 x 2 x 2 block: every edge on a square
    assert swarm.bridges(~two) == 0


def test_quick_anchor_comparison_writes_its_subsection(tmp_path: pathlib.Path) -> None:
    """`--anchor --quick`: the complete arbitration and PIBT against pymapf's LaCAM (its own environment; a row
    of dashes where it cannot be installed) on a small instance, every drone home, in a subsection of its own."""
    out = tmp_path / "BENCHMARKS.md"
    out.write_text("# Benchmarks\n\n## Other\n\nkept\n")
    assert cli(["swarm", "--quick", "--anchor", "--families", "empty-32-32", "--anchor-seconds", "30", "--write",
                "--output", str(out)]) == 0
    text = out.read_text()
    assert "## Other\n\nkept" in text and swarm.ANCHOR_SECTION in text
    rows = [line.split(" | ") for line in text.splitlines() if line.startswith("| empty-32-32 |")]
    assert len(rows) == 1 and rows[0][5] == "10/10" and rows[0][9] == "10/10", rows  # lacam, pibt: all home
    if rows[0][14] == "-":
        print("the anchor (pymapf) could not be installed here: its columns are dashes")
    else:
        assert rows[0][14] == "true", rows


def test_anchor_trace_of_one_seed(capsys) -> None:
    """`--anchor --seed N --trace`: one instance alone, with the complete arbitration's course on stderr (which
    search runs from which turn, found or not), to see why an instance's drones are not home by the limit."""
    assert cli(["swarm", "--anchor", "--families", "room-32-32-4", "--agents", "20", "--seed", "2",
                "--variants", "lacam", "--anchor-seconds", "0", "--trace"]) == 0
    captured = capsys.readouterr()
    rows = [line for line in captured.out.splitlines() if line.startswith("| room-32-32-4 |")]
    assert len(rows) == 1 and rows[0].split(" | ")[2] == "2", rows  # that seed alone
    course = [line for line in captured.err.splitlines() if "room-32-32-4 20: turn " in line]
    assert course and course[0].split(": ", 1)[1].startswith("turn 0: whole, found "), course


def test_the_search_alone_is_timed_turn_by_turn() -> None:
    """`--search-alone`: the search started where the game would start it (its tables made a turn's work at a time:
    an unbounded first turn searched to the goal and refined the plan without end), then timed turn by turn."""
    out = swarm.search_alone([("room-32-32-4", 100), ("city", 1000)], turns=5)
    for mean, p95, longest in out.values():
        assert 0 < mean <= longest and p95 <= longest
