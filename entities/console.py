"""The terminal ground station's protocol (the seed's interactive console), pure: fed the coordinator's messages,
the lines typed at the console and, when the ground station takes them, ROS 2 goals, it says what to do. No
terminal, no network, no clock: the terminal's adapter is `entities.gcs_node`.

Each GCS phase is held (`Station(hold=True)`) until the person answers it: a line of targets (``x,y,z``,
``Dnn x,y,z``, several separated by ``;``; all or nothing: one bad item refuses the line), Enter to keep the
targets, ``q`` to quit. The seed forces a first target: while a drone alive has none, Enter is refused and the
prompt asks for that drone's. A line typed before its prompt waits for the next phase, as a terminal's input does.

With goals (`dronesim gcs --ros2`), a goal taken (`goal`: read and checked by `entities.ros2.goals`) is a target
typed at the console: it answers the phase held (or, coming between two phases, the next one). A drone may then
wait for its goal without a target, hovering: Enter plays the turn, and the prompt names the drones still without
one. The end of the console's input (Ctrl-D, a closed pipe) quits the game, except with goals: the game then goes
on, each phase answered at once, with the goals alone (`dronesim gcs --ros2 < /dev/null` is a ground station of
ROS 2 goals only).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from schema import Cell, Intent, Message, UsageError, Welcome

from .gcs import Effect, Ground, Show, Station, parse_command

#: Drones a prompt names at most (then "and N more": a swarm's prompt stays a line).
PROMPT_NAMES = 6


@dataclass(frozen=True, slots=True)
class Typed:
    """A line typed at the console, without its end of line; None: the console's input has ended."""

    text: str | None


@dataclass(frozen=True, slots=True)
class Prompt:
    """Ask the person at the console: show `text` last (no end of line); a `Typed` line is awaited."""

    text: str


#: What the console's protocol says to do: the station's effects, and its prompts.
Act = Effect | Prompt


def named(drones: list[str], limit: int = PROMPT_NAMES) -> str:
    more = len(drones) - limit
    return ", ".join(drones[:limit]) + (f" and {more} more" if more > 0 else "")


class Console:
    """The console's side of the protocol (the module's docstring), around the `Station` it holds. Times are
    seconds of any monotonic clock."""

    def __init__(self, ground: Ground, *, goals: bool = False, verbose: bool = False) -> None:
        self.station = Station(ground, hold=True, verbose=verbose, goals=goals)
        self.world, self.drones, self.goals = ground.world, list(ground.starts), goals
        self.typed: deque[str | None] = deque()  # lines not used yet, oldest first (None: the input's end)
        self.goal_came = False  # a goal was taken while no phase was held: it answers the next one
        self.closed = False  # the input has ended (with goals: each phase is answered at once from then on)
        self.quitting = False
        self._asked: int | None = None  # the turn held whose prompt is shown, until an input is used

    # the protocol's events (`entities.station_link.Core`)

    def wake(self, now: float) -> float | None:
        return self.station.wake(now)

    def admitted(self, welcome: Welcome) -> list[Effect]:
        return self.station.admitted(welcome)

    def receive(self, msg: Message, now: float) -> list[Act]:
        return [*self.station.receive(msg, now), *self._serve()]

    def tick(self, now: float) -> list[Effect]:
        return self.station.tick(now)

    # the person's and ROS 2's inputs

    def line(self, text: str | None) -> list[Act]:
        """A line typed at the console (None: its input ended)."""
        self.typed.append(text)
        return self._serve()

    def goal(self, drone: str, cell: Cell) -> list[Act]:
        """A goal for `drone`, read and checked against the world (`entities.ros2.goals.Goals`): its target, as if
        typed here. UsageError (``reason: ...``) if it cannot be: an unknown drone, one dead or lost, a game over."""
        self.station.take(drone, cell)
        self.goal_came = True
        return self._serve()

    def missing(self) -> list[str]:
        """The drones alive without a target."""
        wanted, gone = self.station.wanted, self.station.gone
        return [d for d in self.drones if d not in wanted and d not in gone]

    def prompt(self, turn: int) -> str:
        missing = self.missing()
        if not self.goals:
            return (f"turn {turn}: target for {missing[0]} (x,y,z): " if missing else
                    f"turn {turn}: new target ([Dnn] x,y,z; ...), Enter to keep, q to quit: ")
        waiting = f"without a target, hovering: {named(missing)}; " if missing else ""
        return f"turn {turn}: {waiting}new target ([Dnn] x,y,z; ...) or a ROS 2 goal, Enter to keep, q to quit: "

    def _serve(self) -> list[Act]:
        """Answer the phase held with the inputs that came, or prompt for one."""
        effects: list[Act] = []
        while (turn := self.station.pending) is not None:  # (until answered: `answer` clears it)
            if self.quitting or self.closed or self.goal_came:
                self.goal_came = False
                effects += self._answer(turn, Intent.QUIT if self.quitting else Intent.CONTINUE)
            elif self.typed:
                self._asked = None
                effects += self._use(turn, self.typed.popleft())
            else:
                if self._asked != turn:
                    self._asked = turn
                    effects.append(Prompt(self.prompt(turn)))
                break
        return effects

    def _use(self, turn: int, text: str | None) -> list[Act]:
        """A line used in the phase of `turn`: the phase's answer, or what to tell the person (the phase still held)."""
        if text is None:  # the input's end: a quit, but with goals, which go on alone
            self.closed, self.quitting = True, not self.goals
            return [Show("the console's input has ended: ROS 2 goals alone from now on")] if self.goals else []
        line = text.strip()
        if line.lower() in ("q", "quit", "exit"):
            self.quitting = True
            return []
        missing = self.missing()
        if not line:
            if missing and not self.goals:
                return [Show(f"a first target is required for {missing[0]}")]
            return self._answer(turn, Intent.CONTINUE)
        given: dict[str, Cell] = {}
        try:  # all or nothing: one bad item refuses the line
            for part in map(str.strip, line.split(";")):
                if missing and not part.startswith("D"):
                    part = f"{missing[0]} {part}"
                given.update(parse_command(part, self.world.size, self.drones, self.world))
                missing = [d for d in missing if d not in given]
        except UsageError as err:
            return [Show(f"invalid: {err}")]
        self.station.want(given)
        if missing and not self.goals:  # the seed's first targets, drone after drone, in one phase
            return []
        return self._answer(turn, Intent.CONTINUE)

    def _answer(self, turn: int, intent: Intent) -> list[Act]:
        self._asked = None
        return [*self.station.answer(turn, intent)]
