"""The ground station's pure parts (the console's protocol: tests/test_console.py)."""

from __future__ import annotations

import weakref

import pytest

from entities.gcs import (
    Ground,
    Plan,
    correct_form,
    describe,
    format_status,
    parse_command,
    targets_of,
)
from schema import Cause, DroneState, DroneStatus, Intent, Note, Start, Status, UsageError, Welcome, WorldSpec
from world.grid import Building, World

SIZE = (10, 10, 5)
OPEN = World.from_buildings(SIZE, [])
#: A building on (3..4, 3..4), two floors high: (3, 3, 0) and (4, 4, 1) are inside, (3, 3, 2) is its roof.
CITY = World.from_buildings(SIZE, [Building(x=3, y=3, length=2, width=2, height=2)])


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


def test_correct_form_refuses_a_building_cell_given_the_world() -> None:
    for text in ("3,3,0", "4,4,1"):
        with pytest.raises(UsageError, match=r"inside a building: no drone can get there"):
            correct_form(text, SIZE, CITY)
    assert correct_form("3,3,2", SIZE, CITY) == (3, 3, 2)  # on the roof
    assert correct_form("3,3,0", SIZE) == (3, 3, 0)  # no world given: the bounds alone


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


def test_a_plan_or_a_script_with_a_target_inside_a_building_is_refused_at_load(tmp_path) -> None:
    texts = ["D01=1,1,1", "D02=4,3,1@5"]
    with pytest.raises(UsageError, match=r"bad target 'D02=4,3,1@5': \(4, 3, 1\) is inside a building"):
        Plan.parse(texts, SIZE, world=CITY)
    with pytest.raises(UsageError, match="inside a building"):
        Plan.drones_of(texts, SIZE, world=CITY)
    script = tmp_path / "targets.txt"
    script.write_text("1,1,1\nD02=3,4,0@2\n", encoding="utf-8")
    with pytest.raises(UsageError, match=r"\(3, 4, 0\) is inside a building"):
        Plan.load(str(script), SIZE, CITY)
    assert Plan.parse(texts, SIZE).last_turn == 5  # without the world: its bounds alone


def test_a_ground_station_refuses_a_target_inside_a_building_of_its_game() -> None:
    welcome = Welcome(turn=0, sender="SRV", entity="GCS", text="You are connected as GCS",
                      world=WorldSpec(size=SIZE, cells=CITY.packed()),
                      starts=(Start(drone="D01", pos=(0, 0, 0)), Start(drone="D02", pos=(0, 2, 0))))
    with pytest.raises(UsageError, match=r"bad target 'D02=3,3,0@4': \(3, 3, 0\) is inside a building"):
        Ground.from_welcome(welcome, ["9,9,0", "D02=3,3,0@4"], None)
    ground = Ground.from_welcome(welcome, ["9,9,0", "D02=3,3,2@4"], None)  # its roof is fine
    assert ground.plan.at(4) == {"D02": (3, 3, 2)} and ground.world.is_building((3, 3, 0))


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
    assert describe(st("D01", (1, 1, 1), target=(2, 2, 2), note=Note.STUCK)) == \
        "D01 at (1, 1, 1): alive, held up by other drones, target (2, 2, 2)"
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


def test_tracks_keep_each_drones_path_through_the_status_history() -> None:
    from entities.gcs import Tracks

    history = [
        Status(turn=0, sender="OBS", drones=(st("D01", (0, 0, 0)), st("D02", (5, 5, 0)))),
        Status(turn=1, sender="OBS", drones=(st("D01", (1, 0, 0)), st("D02", (5, 5, 0)))),
        Status(turn=2, sender="OBS", drones=(st("D01", (1, 0, 0)), st("D02", (5, 4, 0)))),
        Status(turn=3, sender="OBS", drones=(st("D01", (0, 0, 0)), st("D02", (5, 4, 0), DroneState.DEAD))),
    ]
    tracks = Tracks()
    assert tracks.paths == {}
    for status in history:
        tracks.add(status)
    assert tracks.paths == {"D01": [(0, 0, 0), (1, 0, 0), (0, 0, 0)], "D02": [(5, 5, 0), (5, 4, 0)]}


def test_targets_of() -> None:
    status = Status(turn=1, sender="OBS", drones=(st("D01", (0, 0, 0), target=(1, 1, 1)), st("D02", (1, 0, 0))))
    assert targets_of(status) == {"D01": (1, 1, 1)}


def test_a_script_answers_ahead_up_to_its_next_change() -> None:
    from entities.gcs import Plan, turns_to_answer_ahead

    plan = Plan.parse(["D01=1,1,1@1", "D01=2,2,2@5"], (9, 9, 9))
    assert turns_to_answer_ahead(plan, 1, 1, horizon=2) == [2, 3]
    assert turns_to_answer_ahead(plan, 2, 3, horizon=2) == [4], "3 was answered already; 5 brings a change"
    assert turns_to_answer_ahead(plan, 3, 4, horizon=2) == []
    assert turns_to_answer_ahead(plan, 5, 5, last=7) == [6]
    assert turns_to_answer_ahead(plan, 5, 5, horizon=4) == [6, 7, 8, 9]


# --------------------------------------------------------------------------- the protocol (Station)


from entities.gcs import FINAL_STATUS_WAIT, End, SendDone, Show, Station  # noqa: E402
from schema import EndReason, Over, Phase, Turn  # noqa: E402
from schema.tuning import DONE_RETRY_MIN_S, DONE_RETRY_S, DONE_RETRY_TURNS, PUT_GAP  # noqa: E402


def ground(plan: list[str] = (), drones=("D01", "D02")) -> Ground:
    starts = {d: (0, 2 * i, 0) for i, d in enumerate(drones)}
    return Ground(OPEN, starts, Plan.parse(plan, SIZE))


_CLOCKS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def heard(station: Station, msg) -> list:
    """What `station` does on `msg`, its DONEs paced out (`PUT_GAP` apart: the station's clock goes on by as much as
    they take, one tick each)."""
    now = _CLOCKS.get(station, 0.0)
    effects = list(station.receive(msg, now))
    while (wait := station.wake(now)) is not None and wait <= 2 * PUT_GAP:
        now += wait
        effects += station.tick(now)
    _CLOCKS[station] = now
    return effects


def gcs(t: int) -> Turn:
    return Turn(turn=t, sender="SRV", phase=Phase.GCS)


def status(t: int, *drones: DroneStatus) -> Status:
    return Status(turn=t, sender="OBS", drones=drones)


def sent(effects) -> list[tuple[int, dict, Intent]]:
    """The DONEs among `effects`: (turn, the targets they carry, intent)."""
    return [(e.msg.turn, {a.drone: a.pos for a in e.msg.targets}, e.msg.intent)
            for e in effects if isinstance(e, SendDone)]


def over(t: int, reason: EndReason) -> Over:
    return Over(turn=t, sender="SRV", reason=reason, text="the end")


def test_a_script_answers_its_phase_at_once_and_the_phases_with_nothing_new_ahead() -> None:
    station = Station(ground(["D01=1,1,1", "D02=2,2,2@5"]), ahead=2)
    assert sent(heard(station, gcs(1))) == [(1, {"D01": (1, 1, 1)}, Intent.CONTINUE),
                                                  (2, {}, Intent.CONTINUE), (3, {}, Intent.CONTINUE)]
    # the coordinator does not announce a phase answered ahead: STATUS(1) says turn 2 has begun
    assert sent(heard(station, status(1, st("D01", (1, 0, 0), target=(1, 1, 1)), st("D02", (0, 2, 0))))) \
        == [(4, {}, Intent.CONTINUE)]
    # announced all the same: its DONE ahead was lost on the way (a router's budget kept the first of a burst), so
    # it answers again (and nothing more ahead: 5 brings a change)
    assert station.resent["announced"] == 0
    assert sent(heard(station, gcs(3))) == [(3, {}, Intent.CONTINUE)]
    assert heard(station, gcs(3)) == [], "the phase announced again (after a lost link): answered once more"
    assert station.resent == {"announced": 1}, "counted (bench flood shows it)"
    assert sent(heard(station, gcs(5))) == [(5, {"D02": (2, 2, 2)}, Intent.FINAL),
                                                  (6, {}, Intent.FINAL), (7, {}, Intent.FINAL)]


def test_a_script_keeps_its_answers_ahead_topped_up_one_a_status() -> None:
    """Its DONEs go out PUT_GAP apart (a router's budget), so a batch would not travel together: once it has answered
    `ahead` phases, each STATUS brings one more, up to its plan's next change."""
    station = Station(ground(["D01=1,1,1", "D02=2,2,2@12"]), ahead=8)
    assert [t for t, _, _ in sent(heard(station, gcs(1)))] == list(range(1, 10))  # its phase and 8 ahead
    for t in (1, 2):  # turns 2 and 3 begin: one more each, 8 still answered ahead
        assert sent(heard(station, status(t, st("D01", (1, 0, 0), target=(1, 1, 1)), st("D02", (0, 2, 0))))) \
            == [(9 + t, {}, Intent.CONTINUE)]
    # turn 4 begins: 12 brings a change, so nothing more until its phase
    assert sent(heard(station, status(3, st("D01", (1, 0, 0), target=(1, 1, 1)), st("D02", (0, 2, 0))))) == []
    assert [t for t, _, _ in sent(heard(station, gcs(12)))] == list(range(12, 21))


def test_a_script_told_to_answer_nothing_ahead_answers_each_phase_in_it() -> None:
    station = Station(ground(["D01=1,1,1", "D02=2,2,2@5"]), ahead=0)
    assert sent(heard(station, gcs(1))) == [(1, {"D01": (1, 1, 1)}, Intent.CONTINUE)]
    assert sent(heard(station, status(1, st("D01", (1, 0, 0), target=(1, 1, 1)), st("D02", (0, 2, 0))))) == []
    assert sent(heard(station, gcs(2))) == [(2, {}, Intent.CONTINUE)]


def test_a_script_sends_only_the_targets_that_differ_from_those_in_force() -> None:
    station = Station(ground(["D01=1,1,1", "D01=1,1,1@2"]))
    heard(station, gcs(1))
    heard(station, status(1, st("D01", (1, 0, 0), target=(1, 1, 1)), st("D02", (0, 2, 0))))
    assert sent(heard(station, gcs(2)))[0] == (2, {}, Intent.FINAL)


def test_dead_drones_are_forgotten_and_a_late_station_takes_over_the_targets_in_force() -> None:
    station = Station(ground(["D02=3,3,3@2"]))
    heard(station, status(4, st("D01", (1, 0, 0), target=(5, 5, 0)),
                           st("D02", (0, 2, 0), DroneState.DEAD, target=(4, 4, 4), cause=Cause.BUILDING)))
    assert station.wanted == {"D01": (5, 5, 0)} and station.gone == {"D02"}
    assert station.want({"D02": (1, 1, 1), "D01": (6, 6, 0)}) == {"D01": (6, 6, 0)}
    assert sent(heard(station, gcs(5)))[0] == (5, {"D01": (6, 6, 0)}, Intent.FINAL)


def test_a_target_from_outside_the_plan_is_taken_for_a_drone_flying_and_refused_with_a_reason_else() -> None:
    station = Station(ground(["D01=1,1,1"]), goals=True)
    heard(station, status(0, st("D01", (0, 0, 0)), st("D02", (0, 2, 0), DroneState.LOST, cause=Cause.LOST)))
    station.take("D01", (5, 5, 0))
    for drone, reason in (("D02", "dead or lost: D02"), ("D07", "unknown drone: this game flies D01, D02")):
        with pytest.raises(UsageError, match=f"^{reason}"):
            station.take(drone, (5, 5, 0))
    assert sent(heard(station, gcs(1))) == [(1, {"D01": (1, 1, 1)}, Intent.CONTINUE)]  # the plan's, at its turn
    station.take("D01", (5, 5, 0))
    assert sent(heard(station, gcs(2))) == [(2, {"D01": (5, 5, 0)}, Intent.CONTINUE)]
    heard(station, over(2, EndReason.GCS_QUIT))
    with pytest.raises(UsageError, match="^game over"):
        station.take("D01", (6, 6, 0))


def test_a_held_station_answers_when_told_and_forgets_a_phase_the_coordinator_closed() -> None:
    station = Station(ground(["D01=1,1,1"]), hold=True)
    assert heard(station, gcs(1)) == [] and station.pending == 1
    assert station.wanted == {"D01": (1, 1, 1)}  # the plan's, taken at its turn
    assert sent(station.answer(1, Intent.CONTINUE, {"D02": (2, 2, 2)})) == \
        [(1, {"D01": (1, 1, 1), "D02": (2, 2, 2)}, Intent.CONTINUE)]
    assert station.pending is None
    heard(station, gcs(2))
    heard(station, Turn(turn=2, sender="SRV", phase=Phase.DRONES))  # its GCS deadline passed
    assert station.pending is None


def test_admitted_again_it_answers_again_what_it_had_answered_ahead() -> None:
    station = Station(ground(["D01=1,1,1"]), ahead=2)
    assert len(heard(station, gcs(1))) == 3  # 2 and 3 ahead
    station.admitted(None)  # a restarted coordinator does not know what was said ahead
    assert sent(heard(station, gcs(2)))[0] == (2, {"D01": (1, 1, 1)}, Intent.FINAL)


def test_a_script_that_quits_at_a_turn_says_continue_until_then_and_answers_no_further_ahead() -> None:
    station = Station(ground(["D01=1,1,1"]), quit_at=3)
    assert sent(heard(station, gcs(1))) == [(1, {"D01": (1, 1, 1)}, Intent.CONTINUE), (2, {}, Intent.CONTINUE)]
    assert sent(heard(station, gcs(3))) == [(3, {}, Intent.QUIT)]


def test_it_ends_after_over_once_the_last_status_is_in_or_given_up() -> None:
    station = Station(ground())
    assert station.receive(over(3, EndReason.GCS_QUIT), 10.0) == [End(over(3, EndReason.GCS_QUIT))]  # no STATUS(3)
    station = Station(ground(), verbose=True)
    assert station.receive(over(3, EndReason.ALL_REACHED), 10.0) == []  # STATUS(3) is on its way (another key)
    effects = station.receive(status(3, st("D01", (1, 0, 0)), st("D02", (0, 2, 0))), 10.5)
    assert isinstance(effects[0], Show) and effects[0].text.startswith("turn 3:")
    assert effects[-1] == End(over(3, EndReason.ALL_REACHED))
    assert station.receive(gcs(4), 11.0) == []  # nothing after the end
    station = Station(ground())
    station.receive(over(3, EndReason.TURN_LIMIT), 10.0)
    assert station.wake(11.0) == FINAL_STATUS_WAIT - 1.0 and station.tick(11.0) == []
    assert station.tick(10.0 + FINAL_STATUS_WAIT) == [End(over(3, EndReason.TURN_LIMIT))]
    assert station.wake(20.0) is None and station.tick(20.0) == []


def test_the_report_draws_the_paths_and_counts_each_drones_moves() -> None:
    station = Station(ground(drones=("D01",)))
    for t, pos in enumerate([(0, 0, 0), (1, 0, 0), (1, 0, 0), (2, 0, 0)]):
        heard(station, status(t, st("D01", pos, target=(2, 0, 0))))
    heard(station, over(3, EndReason.ALL_REACHED))
    text = station.report(draw=True)
    assert "Final world with the drones' paths:" in text
    assert text.endswith("GAME OVER at turn 3: ALL_REACHED - the end\n  D01: 2 moves, alive, target (2, 0, 0)")
    assert "Final world" not in station.report(draw=False)
    assert station.opening().startswith("World (10, 10, 5), 0 building cells")


def test_its_dones_go_out_paced_so_that_a_routers_budget_of_puts_keeps_them_all() -> None:
    """Issue 33, 6: a router keeps at most PUT_RATE puts a second from one session on the DONE key (a flood of
    them from a second session is dropped there); a station's answers ahead, sent at once, lost all but the first."""
    station = Station(ground(["D01=1,1,1"]), ahead=2)
    assert sent(station.receive(gcs(1), 5.0)) == [(1, {"D01": (1, 1, 1)}, Intent.FINAL)]
    assert station.wake(5.0) == pytest.approx(PUT_GAP) and station.tick(5.0) == []
    assert sent(station.tick(5.0 + PUT_GAP)) == [(2, {}, Intent.FINAL)]
    assert sent(station.tick(5.0 + 1.5 * PUT_GAP)) == [], "one every PUT_GAP s"
    assert sent(station.tick(5.0 + 2 * PUT_GAP)) == [(3, {}, Intent.FINAL)]


def test_a_phase_announced_before_its_done_ahead_went_out_gets_that_done_first_and_once() -> None:
    """A game faster than the station's pacing announces a phase whose DONE ahead is still queued: that DONE goes
    out next, and only once (a second copy would reach the coordinator turns later, refused as stale: a WARNING in
    every quick `dronesim up`); a queued DONE of a turn already played is not sent."""
    station = Station(ground(["D01=1,1,1"]), ahead=2)
    assert sent(station.receive(gcs(1), 5.0)) == [(1, {"D01": (1, 1, 1)}, Intent.FINAL)]  # 2 and 3 queued
    assert sent(station.receive(gcs(2), 5.0 + PUT_GAP / 10)) == []
    out = [station.tick(5.0 + k * PUT_GAP) for k in range(1, 6)]
    assert [t for effects in out for t, _, _ in sent(effects)] == [2, 3, 4], "2 first, once; then 3 and 4 ahead"
    station = Station(ground(["D01=1,1,1"]), ahead=2)
    station.receive(gcs(1), 5.0)
    station.receive(status(2, st("D01", (1, 0, 0), target=(1, 1, 1)), st("D02", (0, 2, 0))), 5.0 + PUT_GAP / 10)
    later = [t for k in range(1, 6) for t, _, _ in sent(station.tick(5.0 + k * PUT_GAP))]
    assert 2 not in later and later == sorted(later), later


def test_a_phases_done_goes_out_again_until_its_turn_is_played() -> None:
    """A DONE lost on the way must not stall the game: the phase's DONE goes out again DONE_RETRY_S s later, then
    twice as long each time, until that turn's STATUS (the coordinator takes a repeat as nothing new)."""
    station = Station(ground(["D01=1,1,1"]), ahead=0)
    (first,) = station.receive(gcs(1), 0.0)
    assert station.wake(0.0) == pytest.approx(DONE_RETRY_S)
    assert station.tick(DONE_RETRY_S) == [first]
    assert station.tick(2 * DONE_RETRY_S) == [], "then twice as long"
    assert station.tick(3 * DONE_RETRY_S) == [first]
    station.receive(status(1, st("D01", (1, 0, 0), target=(1, 1, 1)), st("D02", (0, 2, 0))), 1.0)
    assert station.wake(1.0) is None and station.tick(100.0) == [], "its turn was played"
    assert station.resent == {"timed out": 2}, "each counted (bench flood shows them)"


def test_a_lost_done_costs_a_few_turns_time() -> None:
    """Once turns have been timed (STATUS after STATUS), a phase's DONE goes out again DONE_RETRY_TURNS turns'
    time later (smoothed), no sooner than DONE_RETRY_MIN_S nor later than DONE_RETRY_S."""
    def retry_after(turn_s: float) -> float:
        station = Station(ground(["D01=1,1,1"]), ahead=0)
        for turn in range(1, 4):
            station.receive(status(turn, st("D01", (0, 0, 0)), st("D02", (0, 2, 0))), turn * turn_s)
        station.receive(gcs(4), 3 * turn_s)
        return station.wake(3 * turn_s)

    assert retry_after(0.05) == pytest.approx(DONE_RETRY_TURNS * 0.05)
    assert retry_after(0.001) == pytest.approx(DONE_RETRY_MIN_S)
    assert retry_after(10.0) == pytest.approx(DONE_RETRY_S)
