"""The console's protocol (entities/console.py), driven by events: the coordinator's messages, lines typed, ROS 2
goals. No terminal, no network."""

from __future__ import annotations

import pytest

from entities.console import Console, Prompt, named
from entities.gcs import Ground, Plan, SendDone, Show
from schema import Cause, DroneState, DroneStatus, Intent, Note, Phase, Status, Turn, UsageError
from world.grid import Building, World

SIZE = (10, 10, 5)
OPEN = World.from_buildings(SIZE, [])
#: A building on (3..4, 3..4), two floors high: (3, 3, 0) and (4, 4, 1) are inside, (3, 3, 2) is its roof.
CITY = World.from_buildings(SIZE, [Building(x=3, y=3, length=2, width=2, height=2)])
DRONES = ("D01", "D02")
FIRST = "turn 1: target for D01 (x,y,z): "
KEEP = "new target ([Dnn] x,y,z; ...), Enter to keep, q to quit: "
GOALS = "new target ([Dnn] x,y,z; ...) or a ROS 2 goal, Enter to keep, q to quit: "


def st(drone: str, pos, state=DroneState.ALIVE, target=None, cause=Cause.NONE) -> DroneStatus:
    return DroneStatus(drone=drone, pos=pos, state=state, target=target, note=Note.NONE, cause=cause)


def gcs(t: int) -> Turn:
    return Turn(turn=t, sender="SRV", phase=Phase.GCS)


class Person:
    """A console and what its person saw: every prompt, every text shown, every DONE sent (turn, targets, intent)."""

    def __init__(self, drones=("D01",), world: World = OPEN, *, goals: bool = False,
                 in_force: dict | None = None) -> None:
        starts = {d: (0, 2 * i, 0) for i, d in enumerate(drones)}
        self.console = Console(Ground(world, starts, Plan(())), goals=goals)
        self.prompts: list[str] = []
        self.shown: list[str] = []
        self.done: list[tuple[int, dict, Intent]] = []
        if in_force is not None:  # a STATUS with the targets in force (the station takes them over)
            self.take(self.console.receive(Status(turn=0, sender="SRV", drones=tuple(
                st(d, c, target=in_force.get(d)) for d, c in starts.items())), 0.0))

    def take(self, effects) -> None:
        for e in effects:
            match e:
                case Prompt(text):
                    self.prompts.append(text)
                case Show(text):
                    self.shown.append(text)
                case SendDone(msg):
                    self.done.append((msg.turn, {a.drone: a.pos for a in msg.targets}, msg.intent))
                case _:
                    raise AssertionError(e)

    def phase(self, turn: int) -> Person:
        self.take(self.console.receive(gcs(turn), 0.0))
        return self

    def type(self, *lines: str | None) -> Person:
        for line in lines:
            self.take(self.console.line(line))
        return self

    def goal(self, drone: str, cell) -> Person:
        self.take(self.console.goal(drone, cell))
        return self


# --------------------------------------------------------------------------- the seed's console (no goals)


def test_the_first_target_is_forced() -> None:
    p = Person().phase(1).type("", "garbage", "99,0,0", "3,4,1")
    assert p.done == [(1, {"D01": (3, 4, 1)}, Intent.CONTINUE)]
    assert p.prompts == [FIRST] * 4
    assert p.shown[0] == "a first target is required for D01"
    assert p.shown[1].startswith("invalid: ") and "type x,y,z" in p.shown[1]
    assert p.shown[2].startswith("invalid: ") and "outside the world" in p.shown[2]
    assert len(p.shown) == 3


def test_a_target_is_forced_for_every_drone_one_after_the_other_in_one_phase() -> None:
    p = Person(DRONES).phase(1).type("1,1,1", "", "2,2,2")
    assert p.done == [(1, {"D01": (1, 1, 1), "D02": (2, 2, 2)}, Intent.CONTINUE)]
    assert p.prompts == [FIRST, "turn 1: target for D02 (x,y,z): ", "turn 1: target for D02 (x,y,z): "]
    assert p.shown == ["a first target is required for D02"]


def test_several_first_targets_on_one_line() -> None:
    assert Person(DRONES).phase(1).type("1,1,1; 2,2,2").done == [(1, {"D01": (1, 1, 1), "D02": (2, 2, 2)},
                                                                  Intent.CONTINUE)]


def test_a_building_cell_is_refused_and_asked_again() -> None:
    p = Person(world=CITY).phase(1).type("3,3,0", "4,4,1", "3,3,2")
    assert p.done == [(1, {"D01": (3, 3, 2)}, Intent.CONTINUE)]
    assert p.shown == ["invalid: (3, 3, 0) is inside a building: no drone can get there",
                       "invalid: (4, 4, 1) is inside a building: no drone can get there"]


def test_enter_keeps_the_targets() -> None:
    p = Person(in_force={"D01": (1, 1, 1)}).phase(2).type("")
    assert p.done == [(2, {}, Intent.CONTINUE)] and p.prompts == [f"turn 2: {KEEP}"] and p.shown == []


@pytest.mark.parametrize("line", ["q", "Q", "quit", "exit", "  q  "])
def test_q_quits(line: str) -> None:
    assert Person(in_force={"D01": (1, 1, 1)}).phase(2).type(line).done == [(2, {}, Intent.QUIT)]


def test_q_quits_even_before_the_first_target() -> None:
    assert Person().phase(1).type("q").done == [(1, {}, Intent.QUIT)]


def test_the_end_of_the_input_quits() -> None:
    assert Person().phase(1).type(None).done == [(1, {}, Intent.QUIT)]
    assert Person(in_force={"D01": (1, 1, 1)}).phase(3).type(None).done == [(3, {}, Intent.QUIT)]
    p = Person(in_force={"D01": (1, 1, 1)}).phase(3).type("nope", None)  # after a refused line: a quit all the same
    assert p.done == [(3, {}, Intent.QUIT)] and len(p.shown) == 1
    assert p.phase(4).done[-1] == (4, {}, Intent.QUIT)  # (and so every phase after it)


def test_one_drone_changed_a_bare_cell_for_the_first() -> None:
    current = {"D01": (1, 1, 1), "D02": (2, 2, 2)}
    assert Person(DRONES, in_force=current).phase(4).type("D02 1,2,3").done == [(4, {"D02": (1, 2, 3)},
                                                                                 Intent.CONTINUE)]
    assert Person(DRONES, in_force=current).phase(4).type("4,4,4").done == [(4, {"D01": (4, 4, 4)}, Intent.CONTINUE)]


def test_a_line_with_one_bad_item_changes_nothing() -> None:
    p = Person(DRONES, in_force={"D01": (1, 1, 1), "D02": (2, 2, 2)}).phase(4)
    p.type("D02 1,2,3; D09 1,1,1", "D01 1,2,3; D02 0,0,99", "")
    assert p.done == [(4, {}, Intent.CONTINUE)]
    assert len(p.shown) == 2 and all(w.startswith("invalid: ") for w in p.shown) and "D09" in p.shown[0]
    assert p.console.station.wanted == {"D01": (1, 1, 1), "D02": (2, 2, 2)}


def test_several_changes_on_one_line() -> None:
    p = Person(DRONES, in_force={"D01": (1, 1, 1), "D02": (2, 2, 2)}).phase(4).type("D02 3,3,3; D01 4,4,4")
    assert p.done == [(4, {"D01": (4, 4, 4), "D02": (3, 3, 3)}, Intent.CONTINUE)]


def test_each_phase_is_asked_in_it_and_none_answered_ahead() -> None:
    p = Person(DRONES).phase(1).type("1,1,1; 2,2,2")
    p.take(p.console.receive(Status(turn=1, sender="SRV", drones=(st("D01", (1, 0, 0), target=(1, 1, 1)),
                                                                   st("D02", (0, 2, 0), target=(2, 2, 2)))), 0.0))
    p.phase(2).type("").phase(3).type("q")
    assert p.done == [(1, {"D01": (1, 1, 1), "D02": (2, 2, 2)}, Intent.CONTINUE), (2, {}, Intent.CONTINUE),
                      (3, {}, Intent.QUIT)]
    assert p.prompts == [FIRST, f"turn 2: {KEEP}", f"turn 3: {KEEP}"]


def test_a_line_typed_before_its_prompt_answers_the_next_phase() -> None:
    p = Person().type("1,1,1")
    assert p.done == [] and p.prompts == []
    assert p.phase(1).done == [(1, {"D01": (1, 1, 1)}, Intent.CONTINUE)] and p.prompts == []


def test_no_first_target_is_asked_for_a_drone_that_died_before_its_first_phase() -> None:
    p = Person(DRONES)
    p.take(p.console.receive(Status(turn=0, sender="SRV", drones=(
        st("D01", (0, 0, 0)), st("D02", (0, 2, 0), DroneState.LOST, cause=Cause.LOST))), 0.0))
    assert p.phase(1).type("1,1,1").done == [(1, {"D01": (1, 1, 1)}, Intent.CONTINUE)]
    assert p.prompts == [FIRST]


def test_the_prompt_is_not_shown_again_for_news_that_answer_nothing() -> None:
    p = Person(DRONES).phase(1)
    p.phase(1)  # the same phase announced again
    p.take(p.console.receive(Status(turn=0, sender="SRV", drones=(st("D01", (0, 0, 0)), st("D02", (0, 2, 0)))), 0.0))
    assert p.prompts == [FIRST]


def test_a_held_turn_the_coordinator_went_past_is_asked_again_for_the_new_one() -> None:
    assert Person().phase(1).phase(2).prompts == [FIRST, "turn 2: target for D01 (x,y,z): "]


# --------------------------------------------------------------------------- with ROS 2 goals


def test_a_goal_is_a_target_typed_at_the_console_it_answers_the_phase() -> None:
    p = Person(DRONES, goals=True).phase(1).goal("D02", (5, 5, 1))
    assert p.done == [(1, {"D02": (5, 5, 1)}, Intent.CONTINUE)]
    assert p.prompts == [f"turn 1: without a target, hovering: D01, D02; {GOALS}"]
    p.phase(2)
    assert p.prompts[-1] == f"turn 2: without a target, hovering: D01; {GOALS}"
    p.type("3,3,3").phase(3)  # a bare cell: the first drone without a target
    assert p.done[-1] == (2, {"D01": (3, 3, 3), "D02": (5, 5, 1)}, Intent.CONTINUE)  # (no STATUS: all sent)
    assert p.prompts[-1] == f"turn 3: {GOALS}"
    p.goal("D01", (4, 4, 4))
    assert p.done[-1] == (3, {"D01": (4, 4, 4), "D02": (5, 5, 1)}, Intent.CONTINUE)
    assert p.shown == []


def test_with_goals_enter_plays_the_turn_the_drones_without_a_target_hover() -> None:
    p = Person(DRONES, goals=True).phase(1).type("").phase(2).type("D02 2,2,2").phase(3).type("")
    assert p.done == [(1, {}, Intent.CONTINUE), (2, {"D02": (2, 2, 2)}, Intent.CONTINUE),
                      (3, {"D02": (2, 2, 2)}, Intent.CONTINUE)]
    assert p.shown == [] and p.prompts[-1] == f"turn 3: without a target, hovering: D01; {GOALS}"


def test_a_goal_between_two_phases_answers_the_next_one_many_goals_once() -> None:
    p = Person(DRONES, goals=True).phase(1).type("1,1,1; 2,2,2")
    p.goal("D01", (6, 6, 0)).goal("D02", (7, 7, 0))  # while the coordinator plays turn 1
    assert p.phase(2).done[-1] == (2, {"D01": (6, 6, 0), "D02": (7, 7, 0)}, Intent.CONTINUE)
    assert p.prompts == [f"turn 1: without a target, hovering: D01, D02; {GOALS}"]  # none for turn 2
    p.phase(3)
    assert p.prompts[-1] == f"turn 3: {GOALS}" and len(p.done) == 2  # the goals answered one phase


def test_a_goal_for_a_drone_gone_or_after_the_end_is_refused_and_changes_nothing() -> None:
    from schema import EndReason, Over

    p = Person(DRONES, goals=True)
    p.take(p.console.receive(Status(turn=0, sender="SRV", drones=(
        st("D01", (0, 0, 0)), st("D02", (0, 2, 0), DroneState.DEAD, cause=Cause.BUILDING))), 0.0))
    p.phase(1)
    with pytest.raises(UsageError, match=r"^dead or lost: D02 takes no more targets"):
        p.goal("D02", (1, 1, 1))
    with pytest.raises(UsageError, match=r"^unknown drone: this game flies D01, D02"):
        p.goal("D07", (1, 1, 1))
    assert p.done == [] and p.console.station.wanted == {} and p.console.station.pending == 1
    assert p.console.receive(Over(turn=1, sender="SRV", reason=EndReason.GCS_QUIT, text=""), 0.0)  # (its End)
    with pytest.raises(UsageError, match=r"^game over: no more targets"):
        p.goal("D01", (1, 1, 1))


def test_with_goals_the_end_of_the_input_leaves_the_goals_alone_it_does_not_quit() -> None:
    p = Person(goals=True).phase(1).type(None)
    assert p.done == [(1, {}, Intent.CONTINUE)]
    assert p.shown == ["the console's input has ended: ROS 2 goals alone from now on"]
    p.phase(2).goal("D01", (2, 2, 2)).phase(3)
    assert p.done[1:] == [(2, {}, Intent.CONTINUE), (3, {"D01": (2, 2, 2)}, Intent.CONTINUE)]
    assert p.prompts == [f"turn 1: without a target, hovering: D01; {GOALS}"]  # asked nothing since
    assert Person(goals=True).phase(1).type("q").done == [(1, {}, Intent.QUIT)]  # q quits as ever


def test_a_swarm_prompt_names_a_few_drones() -> None:
    assert named([f"D{i:02d}" for i in range(1, 10)], limit=3) == "D01, D02, D03 and 6 more"
    assert named(["D01", "D02"], limit=3) == "D01, D02"


def test_the_screen_keeps_the_prompt_last_until_its_phase_is_answered() -> None:
    import io

    from entities.gcs_node import Screen

    out = io.StringIO()
    screen = Screen(out, echoed=False)
    screen.ask("turn 1: ? ")
    screen.show("refused a ROS 2 goal for D01: other frame")
    screen.answered()  # (the goal answered the phase: its DONE went out before its line is shown)
    screen.show("ROS 2 goal: D01 -> (1, 1, 1)")
    screen.show("turn 1:")
    screen.ask("turn 2: ? ")
    screen.typed()  # a pipe's line: the prompt's line goes on until something else is shown
    screen.answered()
    screen.show("turn 2:")
    assert out.getvalue() == ("turn 1: ? \nrefused a ROS 2 goal for D01: other frame\nturn 1: ? \n"
                              "ROS 2 goal: D01 -> (1, 1, 1)\nturn 1:\nturn 2: ? \nturn 2:\n")
    echoed = Screen(out := io.StringIO(), echoed=True)  # a terminal's echo ends the prompt's line
    echoed.ask("turn 1: ? ")
    echoed.typed()
    echoed.answered()
    echoed.show("turn 1:")
    assert out.getvalue() == "turn 1: ? turn 1:\n"
