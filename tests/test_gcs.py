"""The ground station's pure parts and its interactive console, driven by a scripted reader."""

from __future__ import annotations

import pytest

from dronesim.entities.gcs import Plan, correct_form, describe, format_status, parse_command, targets_of, trails
from dronesim.schema import Cause, DroneState, DroneStatus, Intent, Note, Status, UsageError

SIZE = (10, 10, 5)


# --------------------------------------------------------------------------- correct_form


@pytest.mark.parametrize("text,cell", [
    ("1,2,3", (1, 2, 3)),
    ("0,0,0", (0, 0, 0)),
    ("9,9,4", (9, 9, 4)),
    (" 1 , 2 , 3 ", (1, 2, 3)),
    ("1 2 3", (1, 2, 3)),
    ("1, 2, 3\n", (1, 2, 3)),
])
def test_correct_form_inside(text: str, cell) -> None:
    assert correct_form(text, SIZE) == cell


@pytest.mark.parametrize("text", ["10,0,0", "0,10,0", "0,0,5", "-1,0,0", "0,-1,0", "0,0,-1", "99,99,99"])
def test_correct_form_outside(text: str) -> None:
    with pytest.raises(UsageError, match="outside the world"):
        correct_form(text, SIZE)


@pytest.mark.parametrize("text", ["", "   ", "abc", "1,2", "1,2,3,4", "1.5,2,3", "x,y,z", "1;2;3", "(1,2,3)",
                                  "1,2,three"])
def test_correct_form_garbage(text: str) -> None:
    with pytest.raises(UsageError, match="is not x,y,z"):
        correct_form(text, SIZE)


# --------------------------------------------------------------------------- plans


def test_plan_default_drone_from_turn_1() -> None:
    plan = Plan.parse(["9,9,0"], SIZE)
    assert plan.items == ((1, "D01", (9, 9, 0)),)
    assert plan.at(1) == {"D01": (9, 9, 0)}
    assert plan.at(2) == {}
    assert plan.last_turn == 1
    assert plan.drones() == {"D01"}


def test_plan_named_drone_and_turn() -> None:
    plan = Plan.parse(["D02=3,4,0@5"], SIZE)
    assert plan.items == ((5, "D02", (3, 4, 0)),)
    assert plan.at(5) == {"D02": (3, 4, 0)}
    assert plan.at(1) == {}
    assert plan.last_turn == 5


def test_plan_default_drone_argument() -> None:
    assert Plan.parse(["1,1,1"], SIZE, default_drone="D07").items == ((1, "D07", (1, 1, 1)),)


def test_plan_semicolons_comments_and_sorting() -> None:
    plan = Plan.parse([
        "D02=3,4,0@5; 9,9,0",
        "# a comment line",
        "",
        "  ; ;",
        "D03 1, 2, 3 @ 2",
        "D01=0,0,1@12",
    ], SIZE)
    assert plan.items == ((1, "D01", (9, 9, 0)), (2, "D03", (1, 2, 3)), (5, "D02", (3, 4, 0)),
                          (12, "D01", (0, 0, 1)))
    assert plan.at(1) == {"D01": (9, 9, 0)}
    assert plan.at(2) == {"D03": (1, 2, 3)}
    assert plan.at(12) == {"D01": (0, 0, 1)}
    assert plan.last_turn == 12
    assert plan.drones() == {"D01", "D02", "D03"}


def test_plan_several_drones_same_turn() -> None:
    plan = Plan.parse(["D01=1,1,1;D02=2,2,2;D10=3,3,3"], SIZE)
    assert plan.at(1) == {"D01": (1, 1, 1), "D02": (2, 2, 2), "D10": (3, 3, 3)}


def test_plan_at_is_each_turns_items_with_the_last_written_winning() -> None:
    """`Plan.at` finds a turn's items by bisection: the same as reading every item, on random plans."""
    import random

    rng = random.Random(5)
    for _ in range(50):
        texts = [f"D{rng.randint(1, 4):02d}={rng.randint(0, 9)},{rng.randint(0, 9)},0@{rng.randint(1, 12)}"
                 for _ in range(rng.randint(0, 30))]
        plan = Plan.parse(texts, (10, 10, 10))
        for turn in range(0, 15):
            expected = {}
            for t, d, c in plan.items:
                if t == turn:
                    expected[d] = c
            assert plan.at(turn) == expected


def test_empty_plan() -> None:
    plan = Plan.parse([], SIZE)
    assert plan.items == ()
    assert plan.last_turn == 0
    assert plan.at(1) == {}


@pytest.mark.parametrize("text,match", [
    ("garbage", "expected \\[Dnn=\\]x,y,z\\[@turn\\]"),
    ("1,2", "expected"),
    ("D1=1,2,3", "expected"),
    ("X01=1,2,3", "expected"),
    ("1,2,3@", "expected"),
    ("1,2,3@-1", "expected"),
    ("1,2,3@0", "turns start at 1"),
    ("10,0,0", "outside the world"),
    ("D02=0,0,5@3", "outside the world"),
    ("-1,0,0", "outside the world"),
    ("1,2,3; nope", "'nope'"),
    ("9,9,0 # trailing comment", "expected"),
])
def test_plan_errors(text: str, match: str) -> None:
    with pytest.raises(UsageError, match=match):
        Plan.parse([text], SIZE)


def test_plan_load_strips_comments(tmp_path) -> None:
    path = tmp_path / "targets.txt"
    path.write_text("# scripted targets\n9,9,0   # first\n\nD02=3,4,0@5\nD01=1,1,1@3 # later\n", encoding="utf-8")
    plan = Plan.load(str(path), SIZE)
    assert plan.items == ((1, "D01", (9, 9, 0)), (3, "D01", (1, 1, 1)), (5, "D02", (3, 4, 0)))


def test_plan_load_errors(tmp_path) -> None:
    with pytest.raises(UsageError, match="cannot read the target script"):
        Plan.load(str(tmp_path / "missing.txt"), SIZE)
    bad = tmp_path / "bad.txt"
    bad.write_text("1,2,3\nwhat\n", encoding="utf-8")
    with pytest.raises(UsageError, match="'what'"):
        Plan.load(str(bad), SIZE)


# --------------------------------------------------------------------------- interactive commands


DRONES = ["D01", "D02"]


@pytest.mark.parametrize("line,expected", [
    ("1,2,3", {"D01": (1, 2, 3)}),
    ("1, 2 ,3", {"D01": (1, 2, 3)}),
    ("D02 4,5,1", {"D02": (4, 5, 1)}),
    ("D02=4,5,1", {"D02": (4, 5, 1)}),
    ("  D01   0,0,0  ", {"D01": (0, 0, 0)}),
])
def test_parse_command(line: str, expected: dict) -> None:
    assert parse_command(line, SIZE, DRONES) == expected


@pytest.mark.parametrize("line,match", [
    ("", "type x,y,z or Dnn x,y,z"),
    ("hello", "type x,y,z or Dnn x,y,z"),
    ("1,2,3@4", "type x,y,z or Dnn x,y,z"),
    ("D09 1,2,3", "unknown drone D09: this game flies D01, D02"),
    ("D01 1,2,9", "outside the world"),
    ("D01 -1,2,3", "outside the world"),
])
def test_parse_command_errors(line: str, match: str) -> None:
    with pytest.raises(UsageError, match=match):
        parse_command(line, SIZE, DRONES)


# --------------------------------------------------------------------------- display


def st(drone, pos, state=DroneState.ALIVE, target=None, note=Note.NONE, cause=Cause.NONE) -> DroneStatus:
    return DroneStatus(drone=drone, pos=pos, state=state, target=target, note=note, cause=cause)


def test_describe() -> None:
    assert describe(st("D01", (1, 2, 3), target=(9, 9, 0))) == "D01 at (1, 2, 3): alive, target (9, 9, 0)"
    assert describe(st("D01", (1, 2, 3))) == "D01 at (1, 2, 3): alive, no target"
    assert describe(st("D01", (9, 9, 0), target=(9, 9, 0), note=Note.REACHED)) == \
        "D01 at (9, 9, 0): reached its target, target (9, 9, 0)"
    assert describe(st("D01", (1, 1, 1), target=(2, 2, 2), note=Note.UNREACHABLE)) == \
        "D01 at (1, 1, 1): target UNREACHABLE, hovering, target (2, 2, 2)"
    assert describe(st("D02", (1, 0, 0), DroneState.DEAD, cause=Cause.BUILDING)) == \
        "D02 at (1, 0, 0): DEAD (building), no target"
    assert describe(st("D02", (-1, 0, 0), DroneState.DEAD, (3, 3, 3), cause=Cause.OUTSIDE)) == \
        "D02 at (-1, 0, 0): DEAD (outside), target (3, 3, 3)"
    assert describe(st("D03", (0, 0, 0), DroneState.LOST, cause=Cause.LOST)) == \
        "D03 at (0, 0, 0): LOST (lost), no target"


def test_format_status() -> None:
    status = Status(turn=3, sender="OBS", drones=(
        st("D01", (1, 0, 0), target=(9, 9, 0)),
        st("D02", (0, 1, 0), DroneState.DEAD, cause=Cause.VERTEX),
    ))
    assert format_status(status) == (
        "turn 3:\n"
        "  D01 at (1, 0, 0): alive, target (9, 9, 0)\n"
        "  D02 at (0, 1, 0): DEAD (vertex), no target"
    )
    assert format_status(Status(turn=0, sender="OBS", drones=())) == "turn 0:"


def test_format_status_limits_long_swarms() -> None:
    drones = tuple(st(f"D{i:02d}", (i, 0, 0), DroneState.DEAD if i % 4 == 0 else DroneState.ALIVE)
                   for i in range(1, 21))
    text = format_status(Status(turn=7, sender="OBS", drones=drones), limit=5)
    lines = text.split("\n")
    assert lines[0] == "turn 7:"
    assert len(lines) == 1 + 5 + 1
    assert lines[1].startswith("  D01 at") and lines[5].startswith("  D05 at")
    assert lines[-1] == "  ... 15 more; totals: {'ALIVE': 15, 'DEAD': 5}"
    assert len(format_status(Status(turn=7, sender="OBS", drones=drones)).split("\n")) == 1 + 16 + 1


def test_trails() -> None:
    history = [
        Status(turn=0, sender="OBS", drones=(st("D01", (0, 0, 0)), st("D02", (5, 5, 0)))),
        Status(turn=1, sender="OBS", drones=(st("D01", (1, 0, 0)), st("D02", (5, 5, 0)))),
        Status(turn=2, sender="OBS", drones=(st("D01", (1, 0, 0)), st("D02", (5, 4, 0)))),
        Status(turn=3, sender="OBS", drones=(st("D01", (0, 0, 0)), st("D02", (5, 4, 0), DroneState.DEAD))),
    ]
    assert trails(history) == {"D01": [(0, 0, 0), (1, 0, 0), (0, 0, 0)], "D02": [(5, 5, 0), (5, 4, 0)]}
    assert trails([]) == {}


def test_targets_of() -> None:
    status = Status(turn=1, sender="OBS", drones=(st("D01", (0, 0, 0), target=(1, 1, 1)), st("D02", (1, 0, 0))))
    assert targets_of(status) == {"D01": (1, 1, 1)}


# --------------------------------------------------------------------------- the console


class Script:
    """A scripted `read`: returns the lines in order, then raises EOFError."""

    def __init__(self, *lines: str) -> None:
        self.lines = list(lines)
        self.prompts: list[str] = []
        self.written: list[str] = []

    def read(self, prompt: str) -> str:
        self.prompts.append(prompt)
        if not self.lines:
            raise EOFError
        return self.lines.pop(0)

    def write(self, text: str) -> None:
        self.written.append(text)


@pytest.fixture
def gcs_node():
    from dronesim.entities import gcs_node

    return gcs_node


def console(gcs_node, script: Script, drones=("D01",)):
    return gcs_node.Console(SIZE, list(drones), read=script.read, write=script.write)


def test_console_forces_the_first_target(gcs_node) -> None:
    s = Script("", "garbage", "99,0,0", "3,4,1")
    new, intent = console(gcs_node, s).ask(1, {})
    assert (new, intent) == ({"D01": (3, 4, 1)}, Intent.CONTINUE)
    assert s.prompts == ["turn 1: target for D01 (x,y,z): "] * 4
    assert s.written[0] == "a first target is required for D01"
    assert s.written[1].startswith("invalid: ") and "type x,y,z" in s.written[1]
    assert s.written[2].startswith("invalid: ") and "outside the world" in s.written[2]
    assert len(s.written) == 3


def test_console_forces_a_target_for_every_drone(gcs_node) -> None:
    s = Script("1,1,1", "", "2,2,2")
    new, intent = console(gcs_node, s, DRONES).ask(1, {})
    assert (new, intent) == ({"D01": (1, 1, 1), "D02": (2, 2, 2)}, Intent.CONTINUE)
    assert s.prompts == ["turn 1: target for D01 (x,y,z): ", "turn 1: target for D02 (x,y,z): ",
                         "turn 1: target for D02 (x,y,z): "]
    assert s.written == ["a first target is required for D02"]


def test_console_several_first_targets_on_one_line(gcs_node) -> None:
    s = Script("1,1,1; 2,2,2")
    assert console(gcs_node, s, DRONES).ask(1, {}) == ({"D01": (1, 1, 1), "D02": (2, 2, 2)}, Intent.CONTINUE)


def test_console_enter_keeps(gcs_node) -> None:
    s = Script("")
    assert console(gcs_node, s).ask(2, {"D01": (1, 1, 1)}) == ({}, Intent.CONTINUE)
    assert s.prompts == ["turn 2: new target ([Dnn] x,y,z; ...), Enter to keep, q to quit: "]
    assert s.written == []


@pytest.mark.parametrize("line", ["q", "Q", "quit", "exit", "  q  "])
def test_console_q_quits(gcs_node, line: str) -> None:
    assert console(gcs_node, Script(line)).ask(2, {"D01": (1, 1, 1)}) == ({}, Intent.QUIT)


def test_console_q_quits_even_before_the_first_target(gcs_node) -> None:
    assert console(gcs_node, Script("q")).ask(1, {}) == ({}, Intent.QUIT)


def test_console_eof_quits(gcs_node) -> None:
    assert console(gcs_node, Script()).ask(1, {}) == ({}, Intent.QUIT)
    assert console(gcs_node, Script()).ask(3, {"D01": (1, 1, 1)}) == ({}, Intent.QUIT)
    # EOF after a refused line: still a clean quit
    assert console(gcs_node, Script("nope")).ask(3, {"D01": (1, 1, 1)}) == ({}, Intent.QUIT)


def test_console_changes_one_drone(gcs_node) -> None:
    current = {"D01": (1, 1, 1), "D02": (2, 2, 2)}
    s = Script("D02 1,2,3")
    assert console(gcs_node, s, DRONES).ask(4, current) == ({"D02": (1, 2, 3)}, Intent.CONTINUE)
    s = Script("4,4,4")
    assert console(gcs_node, s, DRONES).ask(4, current) == ({"D01": (4, 4, 4)}, Intent.CONTINUE)


def test_console_line_with_one_bad_item_changes_nothing(gcs_node) -> None:
    current = {"D01": (1, 1, 1), "D02": (2, 2, 2)}
    s = Script("D02 1,2,3; D09 1,1,1", "D01 1,2,3; D02 0,0,99", "")
    new, intent = console(gcs_node, s, DRONES).ask(4, current)
    assert (new, intent) == ({}, Intent.CONTINUE)
    assert len(s.written) == 2 and all(w.startswith("invalid: ") for w in s.written)
    assert "D09" in s.written[0]
    assert current == {"D01": (1, 1, 1), "D02": (2, 2, 2)}


def test_console_several_changes_on_one_line(gcs_node) -> None:
    current = {"D01": (1, 1, 1), "D02": (2, 2, 2)}
    s = Script("D02 3,3,3; D01 4,4,4")
    assert console(gcs_node, s, DRONES).ask(4, current) == ({"D01": (4, 4, 4), "D02": (3, 3, 3)}, Intent.CONTINUE)


def test_a_script_answers_ahead_up_to_its_next_change() -> None:
    from dronesim.entities.gcs import Plan, turns_to_answer_ahead

    plan = Plan.parse(["D01=1,1,1@1", "D01=2,2,2@5"], (9, 9, 9))
    assert turns_to_answer_ahead(plan, 1, 1) == [2, 3]
    assert turns_to_answer_ahead(plan, 2, 3) == [4], "3 was answered already; 5 brings a change"
    assert turns_to_answer_ahead(plan, 3, 4) == []
    assert turns_to_answer_ahead(plan, 5, 5, last=7) == [6]
    assert turns_to_answer_ahead(plan, 5, 5, horizon=4) == [6, 7, 8, 9]
