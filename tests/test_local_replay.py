"""The in-process game (dronesim/local.py) and the journal replay (dronesim/replay.py, coordinator/journal.py).

No network: `simulate` wires the Engine, the Environment and the autopilots by function calls.
"""

from __future__ import annotations

import json
import logging
import pathlib

import pytest

from coordinator import journal
from coordinator.journal import dumps
from dronesim import replay
from dronesim.local import Inputs, Result, simulate
from dronesim.scenario import Scenario
from schema import DroneState, EndReason, Intent, UsageError

ROOT = pathlib.Path(__file__).resolve().parent.parent
SWARM16 = ROOT / "scenarios" / "swarm16.json"
QUIET = logging.getLogger("dronesim.tests.local")
QUIET.addHandler(logging.NullHandler())
QUIET.propagate = False


def run(scenario: Scenario, inputs: Inputs | None = None, **config: object) -> Result:
    return simulate(scenario.game_config(**config), scenario.autopilots, inputs or Inputs(plan=scenario.plan()),
                    QUIET, keep_statuses=True)


def write(path: pathlib.Path, records: list[dict], tail: str = "") -> pathlib.Path:
    path.write_text("".join(dumps(r) + "\n" for r in records) + tail, encoding="utf-8")
    return path


def deaths_of(records: list[dict]) -> dict[str, str]:
    return {d: c for r in records for d, c in r.get("deaths", {}).items()}


@pytest.fixture(scope="module")
def swarm() -> Scenario:
    return Scenario.load(SWARM16)


@pytest.fixture(scope="module")
def swarm_run(swarm: Scenario) -> Result:
    return run(swarm)


@pytest.fixture
def swarm_journal(tmp_path: pathlib.Path, swarm_run: Result) -> pathlib.Path:
    return write(tmp_path / "swarm16.jsonl", swarm_run.records)


def by_pilot(scenario: Scenario, name: str) -> set[str]:
    return {d for d, p in scenario.autopilots.items() if p == name}


# --------------------------------------------------------------------------- simulate on swarm16


def test_swarm16_ends_with_every_alive_drone_at_its_target(swarm: Scenario, swarm_run: Result) -> None:
    over = swarm_run.over
    assert over.reason is EndReason.ALL_REACHED
    assert over.turn < swarm.max_turns
    recs = swarm_run.records
    assert recs[0]["record"] == "header" and recs[-1]["record"] == "over"
    assert recs[-1]["reason"] == "ALL_REACHED" and recs[-1]["turn"] == over.turn
    assert [r["turn"] for r in recs[1:-1]] == list(range(1, over.turn + 1))
    final = swarm_run.statuses[-1]
    targets = swarm.plan().at(1)
    for s in final.drones:
        if s.state is DroneState.ALIVE:
            assert s.pos == targets[s.drone]


def test_swarm16_deaths(swarm: Scenario, swarm_run: Result) -> None:
    dead = deaths_of(swarm_run.records)
    v1, seed, dstar = by_pilot(swarm, "v1"), by_pilot(swarm, "seed"), by_pilot(swarm, "dstar")
    assert v1 and seed and dstar
    assert {d: dead.get(d) for d in v1} == {d: "BUILDING" for d in v1}  # the dumb V1 drones hit buildings
    seed_deaths = {d: c for d, c in dead.items() if d in seed}
    assert seed_deaths and set(seed_deaths.values()) == {"VERTEX"}  # seed drones know nothing of each other
    assert not dstar & set(dead), "a cooperative (dstar) drone died"
    final = {s.drone: s for s in swarm_run.statuses[-1].drones}
    assert all(final[d].state is DroneState.ALIVE for d in dstar)
    assert {d for d, s in final.items() if s.state is DroneState.DEAD} == set(dead)


def test_swarm16_only_cooperative_drones_yield(swarm: Scenario, swarm_run: Result) -> None:
    yielded = {d for r in swarm_run.records for d in r.get("yielded", ())}
    assert yielded and yielded <= by_pilot(swarm, "dstar")


def test_swarm16_is_deterministic(swarm: Scenario, swarm_run: Result) -> None:
    again = run(swarm)
    assert [dumps(r) for r in again.records] == [dumps(r) for r in swarm_run.records]
    assert again.over == swarm_run.over


def test_swarm_hosts_play_the_same_game(swarm: Scenario, swarm_run: Result) -> None:
    """One host per autopilot (the seed's drones flown by SeedSwarm, one MOVES a host) writes the journal
    of a process per drone, STATUS for STATUS; missed turns need the per-drone layout."""
    for least in (1, 100):  # SeedSwarm for the 4 seed drones; one SeedPilot each
        hosted = simulate(swarm.game_config(), swarm.autopilots, Inputs(plan=swarm.plan()), QUIET,
                          keep_statuses=True, swarm=True, swarm_min=least)
        assert hosted.records == swarm_run.records and hosted.statuses == swarm_run.statuses
    with pytest.raises(UsageError, match="one process per drone"):
        simulate(swarm.game_config(), swarm.autopilots, Inputs(plan=swarm.plan(), hovered={3: {"D07"}}), QUIET,
                 swarm=True)


def test_statuses_are_kept_only_on_request(swarm: Scenario) -> None:
    s = Scenario.from_json({"format": "dronesim-scenario", "version": 1, "world": {"size": [6, 6, 2], "seed": 1},
                            "drones": [{"id": "D01", "start": [0, 0, 0], "autopilot": "dstar"}],
                            "targets": ["D01=0,3,0"]})
    result = simulate(s.game_config(), s.autopilots, Inputs(plan=s.plan()), QUIET)
    assert result.statuses == []
    assert result.over.reason is EndReason.ALL_REACHED and result.over.turn == 3


# --------------------------------------------------------------------------- journal and verify


def test_journal_written_with_dumps_is_canonical(swarm_journal: pathlib.Path, swarm_run: Result) -> None:
    lines = swarm_journal.read_text(encoding="utf-8").splitlines()
    assert len(lines) == len(swarm_run.records)
    for line in lines:
        assert line == json.dumps(json.loads(line), sort_keys=True, separators=(",", ":"))
    assert list(journal.read(swarm_journal)) == swarm_run.records


def test_inputs_of_recovers_the_plan(swarm: Scenario, swarm_run: Result) -> None:
    inputs = replay.inputs_of(swarm_run.records, swarm.world.size)
    assert inputs.plan.items == swarm.plan().items
    assert inputs.hovered == {} and inputs.vanished == {}
    assert inputs.intent(1) is Intent.FINAL


def test_verify_passes_on_a_faithful_journal(swarm_journal: pathlib.Path) -> None:
    records = list(journal.read(swarm_journal))
    config, autopilots = replay.header_config(records[0])
    assert replay.verify(str(swarm_journal), records, config, autopilots) is None


@pytest.mark.parametrize("what", ["move", "state", "death", "over"])
def test_verify_names_the_tampered_line(tmp_path: pathlib.Path, swarm_run: Result, what: str) -> None:
    records = json.loads(json.dumps(swarm_run.records))
    if what == "move":
        n, rec = 6, records[5]  # turn 5
        d = sorted(rec["moves"])[0]
        rec["moves"][d][2] += 1
    elif what == "state":
        n, rec = 11, records[10]
        rec["state"] = "0" * 16
    elif what == "death":
        n = next(i for i, r in enumerate(records, 1) if r.get("deaths"))
        rec = records[n - 1]
        rec["deaths"] = {d: "OUTSIDE" for d in rec["deaths"]}
    else:
        n, rec = len(records), records[-1]
        rec["text"] = "it was fine"
    path = write(tmp_path / "tampered.jsonl", records)
    config, autopilots = replay.header_config(records[0])
    diff = replay.verify(str(path), records, config, autopilots)
    assert diff is not None
    assert diff.startswith(f"{path}:{n}:")
    assert dumps(rec) in diff


def test_verify_reports_missing_and_extra_records(tmp_path: pathlib.Path, swarm_run: Result) -> None:
    config, autopilots = replay.header_config(swarm_run.records[0])
    unfinished = swarm_run.records[:-1]  # no over record (a crash, a full disk): checked as far as it goes
    assert replay.verify("j", unfinished, config, autopilots) is None
    assert replay.verify("j", swarm_run.records[:3], config, autopilots) is None
    short = swarm_run.records[:-2] + swarm_run.records[-1:]  # its last turn lost, its over record kept
    diff = replay.verify("j", short, config, autopilots)
    assert diff is not None and diff.startswith(f"j:{len(short)}: journal has"), diff
    longer = swarm_run.records + [{"record": "note"}]
    assert "records" in replay.verify("j", longer, config, autopilots)


@pytest.mark.parametrize("reason", ["INTERRUPTED", "ABORTED"])
def test_verify_checks_a_game_ended_from_outside_up_to_its_over_record(swarm_run: Result, reason: str) -> None:
    """A coordinator stopped by a signal (INTERRUPTED) or left by its environment (ABORTED) after turn t: its
    journal verifies up to t (the re-simulation cannot replay the stop, and plays on); an over record that does not
    close the last turn played, or a turn tampered before it, fails."""
    config, autopilots = replay.header_config(swarm_run.records[0])
    t = 5
    played = [r for r in swarm_run.records if not journal.is_over(r) and r.get("turn", 0) <= t]
    over = {"record": "over", "reason": reason, "text": "the coordinator was stopped (SIGINT)", "turn": t}
    assert replay.verify("j", [*played, over], config, autopilots) is None
    assert "is at turn 4, its last turn is 5" in replay.verify("j", [*played, {**over, "turn": 4}], config,
                                                               autopilots)
    tampered = json.loads(json.dumps(played))
    tampered[-1]["state"] = "0" * 16
    assert replay.verify("j", [*tampered, over], config, autopilots).startswith(f"j:{len(played)}:")
    quit_early = [*played, {**over, "reason": "GCS_QUIT"}]  # an end the inputs say: replayed, not taken as said
    assert replay.verify("j", quit_early, config, autopilots) is not None


# --------------------------------------------------------------------------- replay main


def test_main_verify(swarm_journal: pathlib.Path, swarm_run: Result, capsys: pytest.CaptureFixture) -> None:
    assert replay.main([str(swarm_journal), "--verify"]) == 0
    out = capsys.readouterr().out
    last = swarm_run.over.turn
    assert out.startswith(f"after turn {last}:\n")
    assert "z = 0" in out
    assert f"OVER at turn {last}: ALL_REACHED" in out
    assert "D11: DEAD (building)" in out
    assert out.rstrip().endswith(f"verified: a fresh re-simulation writes this journal byte for byte "
                                 f"({len(swarm_run.records)} records)")


def test_main_verify_fails_on_a_tampered_journal(tmp_path: pathlib.Path, swarm_run: Result,
                                                 capsys: pytest.CaptureFixture) -> None:
    records = json.loads(json.dumps(swarm_run.records))
    records[3]["state"] = "f" * 16
    path = write(tmp_path / "t.jsonl", records)
    assert replay.main([str(path), "--verify"]) == 1
    out = capsys.readouterr().out
    assert f"VERIFY FAILED: {path}:4:" in out
    assert "verified" not in out


def test_main_without_verify_does_not_check(tmp_path: pathlib.Path, swarm_run: Result,
                                            capsys: pytest.CaptureFixture) -> None:
    records = json.loads(json.dumps(swarm_run.records))
    records[3]["state"] = "f" * 16
    assert replay.main([str(write(tmp_path / "t.jsonl", records))]) == 0
    assert "verified" not in capsys.readouterr().out


@pytest.mark.parametrize("content", ["", "\n\n", "hello\nworld\n", '{"a": 1}\n', "[1, 2]\n",
                                     '{"record": "turn", "turn": 1}\n',
                                     '{"record": "header", "format": "other"}\n',
                                     '{"record": "header", "format": "dronesim-journal"}\n'],
                         ids=["empty", "blank", "text", "no-record", "list", "no-header", "other-format",
                              "header-without-fields"])
def test_main_not_a_journal(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture, content: str) -> None:
    path = tmp_path / "x.jsonl"
    path.write_text(content, encoding="utf-8")
    assert replay.main([str(path), "--verify"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("dronesim replay: ")
    assert "Traceback" not in err


def test_main_missing_file(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture) -> None:
    assert replay.main([str(tmp_path / "nope.jsonl")]) == 2
    assert "cannot read journal" in capsys.readouterr().err


def test_main_binary_file(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture) -> None:
    path = tmp_path / "x.jsonl"
    path.write_bytes(b"\xff\xfe\x00\x81\n")
    assert replay.main([str(path)]) == 2


@pytest.mark.parametrize("field", ["size", "start"])
def test_main_bad_header_values(tmp_path: pathlib.Path, swarm_run: Result, capsys: pytest.CaptureFixture,
                                field: str) -> None:
    records = json.loads(json.dumps(swarm_run.records))
    if field == "size":
        records[0]["world"]["size"] = [16, 16]
    else:
        records[0]["drones"][0]["start"] = [0, 0]
    assert replay.main([str(write(tmp_path / "h.jsonl", records))]) == 2


@pytest.mark.parametrize("bad", [{"record": "turn"}, {"record": "turn", "turn": 2, "moves": {"D99": [0, 0, 0]}}],
                         ids=["no-turn", "unknown-drone"])
def test_main_malformed_turn_record(tmp_path: pathlib.Path, swarm_run: Result, bad: dict) -> None:
    path = write(tmp_path / "m.jsonl", swarm_run.records[:2] + [bad])
    assert replay.main([str(path)]) in (1, 2)


def test_bad_line_in_the_middle_is_an_error(tmp_path: pathlib.Path, swarm_run: Result,
                                            capsys: pytest.CaptureFixture) -> None:
    lines = [dumps(r) for r in swarm_run.records]
    lines[5] = lines[5][:20]
    path = tmp_path / "mid.jsonl"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(UsageError, match=r"mid\.jsonl:6: not a journal record"):
        list(journal.read(path))
    assert replay.main([str(path)]) == 2
    assert "mid.jsonl:6" in capsys.readouterr().err


def test_torn_last_line_is_ignored(tmp_path: pathlib.Path, swarm_run: Result, capsys: pytest.CaptureFixture) -> None:
    full = dumps(swarm_run.records[-1])
    path = write(tmp_path / "torn.jsonl", swarm_run.records[:-1], tail=full[: len(full) // 2])
    assert list(journal.read(path)) == swarm_run.records[:-1]
    # a crash lost the OVER record: the journal reads, renders, and verifies as far as it goes (unfinished)
    assert replay.main([str(path)]) == 0
    assert "OVER" not in capsys.readouterr().out
    records = list(journal.read(path))
    config, autopilots = replay.header_config(records[0])
    assert replay.verify(str(path), records, config, autopilots) is None
    assert replay.main([str(path), "--verify"]) == 0
    assert f"the game is unfinished: its last turn is {records[-1]['turn']}" in capsys.readouterr().out


def test_torn_line_after_a_complete_journal(tmp_path: pathlib.Path, swarm_journal: pathlib.Path,
                                            capsys: pytest.CaptureFixture) -> None:
    path = tmp_path / "j.jsonl"
    path.write_text(swarm_journal.read_text(encoding="utf-8") + '{"record":"tu', encoding="utf-8")
    assert replay.main([str(path), "--verify"]) == 0
    assert "verified" in capsys.readouterr().out


def test_main_at_renders_the_state_after_that_turn(swarm_journal: pathlib.Path, swarm_run: Result,
                                                  capsys: pytest.CaptureFixture) -> None:
    assert replay.main([str(swarm_journal), "--at", "3"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("after turn 3:\n")
    assert "OVER" not in out
    # each drone's position and state after turn 3, from the records of turns 1..3
    pos = {d["drone"]: tuple(d["start"]) for d in swarm_run.records[0]["drones"]}
    dead: dict[str, str] = {}
    for r in swarm_run.records[1:4]:
        assert r["turn"] <= 3
        pos.update({d: tuple(p) for d, p in r.get("moves", {}).items()})
        dead.update(r.get("deaths", {}))
    assert dead  # some drones died in the first three turns, and more died later
    assert set(deaths_of(swarm_run.records)) - set(dead)
    for d, p in pos.items():
        state = f"DEAD ({dead[d].lower()})" if d in dead else "ALIVE"
        assert f"  {d}: {state} at {p}," in out
    assert replay.tracks(replay.header_config(swarm_run.records[0])[0], swarm_run.records, until=3)[1] == 3


def test_main_turns_prints_one_line_per_turn(swarm_journal: pathlib.Path, swarm_run: Result,
                                             capsys: pytest.CaptureFixture) -> None:
    assert replay.main([str(swarm_journal), "--turns", "--compact"]) == 0
    out = capsys.readouterr().out.splitlines()
    turns = [ln for ln in out if ln.startswith("turn ")]
    assert [ln.split(":")[0] for ln in turns] == [f"turn {t}" for t in range(1, swarm_run.over.turn + 1)]
    assert all(ln.count("D") >= 16 for ln in turns)
    first = swarm_run.records[1]
    for d in first.get("deaths", {}):
        assert f"{d} {tuple(first['moves'][d])} DEAD" in turns[0]
    for d, p in first.get("moves", {}).items():
        assert f"{d} {tuple(p)} " in turns[0]


# --------------------------------------------------------------------------- missed deadlines, vanished drones


def test_hovering_drone_is_lost_and_the_journal_verifies(tmp_path: pathlib.Path, swarm: Scenario,
                                                         capsys: pytest.CaptureFixture) -> None:
    hovered = {2: {"D01"}, 3: {"D01"}, 4: {"D01"}}
    result = run(swarm, Inputs(plan=swarm.plan(), hovered=hovered), lost_after=3)
    turns = {r["turn"]: r for r in result.records if r["record"] == "turn"}
    for t in (2, 3, 4):
        assert turns[t]["hovered"] == ["D01"]
        assert "D01" not in turns[t].get("moves", {})
    assert "lost" not in turns[2] and "lost" not in turns[3]
    assert turns[4]["lost"] == ["D01"]
    assert all("D01" not in r.get("lost", ()) for t, r in turns.items() if t != 4)
    status = {s.drone: s for s in result.statuses[-1].drones}
    assert status["D01"].state is DroneState.LOST
    assert result.records[0]["lost_after"] == 3

    inputs = replay.inputs_of(result.records, swarm.world.size)
    assert inputs.hovered == hovered and inputs.vanished == {}
    path = write(tmp_path / "hover.jsonl", result.records)
    config, autopilots = replay.header_config(result.records[0])
    assert config.lost_after == 3
    assert replay.verify(str(path), result.records, config, autopilots) is None
    assert replay.main([str(path), "--verify"]) == 0
    out = capsys.readouterr().out
    assert "D01: LOST (lost)" in out and "verified" in out


def test_hovering_less_than_lost_after_is_not_lost(swarm: Scenario) -> None:
    result = run(swarm, Inputs(plan=swarm.plan(), hovered={2: {"D01"}, 3: {"D01"}, 5: {"D01"}}), lost_after=3)
    assert not any(r.get("lost") for r in result.records)
    assert {s.drone: s for s in result.statuses[-1].drones}["D01"].state is DroneState.ALIVE


def test_vanished_drone_alongside_a_hovering_one(tmp_path: pathlib.Path, swarm: Scenario) -> None:
    # (with a hovering drone in the same turn the DRONES phase is still open when the deadline is forced)
    result = run(swarm, Inputs(plan=swarm.plan(), vanished={3: {"D02"}}, hovered={3: {"D03"}}))
    turn3 = next(r for r in result.records if r.get("turn") == 3 and r["record"] == "turn")
    assert turn3["lost"] == ["D02"] and turn3["hovered"] == ["D03"]
    assert {s.drone: s for s in result.statuses[-1].drones}["D02"].state is DroneState.LOST
    inputs = replay.inputs_of(result.records, swarm.world.size)
    assert inputs.vanished == {3: {"D02"}} and inputs.hovered == {3: {"D03"}}
    path = write(tmp_path / "v.jsonl", result.records)
    config, autopilots = replay.header_config(result.records[0])
    assert replay.verify(str(path), result.records, config, autopilots) is None


def test_vanished_drone_is_lost_and_the_journal_verifies(tmp_path: pathlib.Path, swarm: Scenario) -> None:
    result = run(swarm, Inputs(plan=swarm.plan(), vanished={3: {"D01"}}))
    turn3 = next(r for r in result.records if r.get("turn") == 3 and r["record"] == "turn")
    assert turn3["lost"] == ["D01"] and "hovered" not in turn3
    assert result.over.reason is not EndReason.ABORTED
    inputs = replay.inputs_of(result.records, swarm.world.size)
    assert inputs.vanished == {3: {"D01"}}
    path = write(tmp_path / "v.jsonl", result.records)
    config, autopilots = replay.header_config(result.records[0])
    assert replay.verify(str(path), result.records, config, autopilots) is None


def test_quit_intent_ends_the_game_and_verifies(tmp_path: pathlib.Path, swarm: Scenario) -> None:
    result = run(swarm, Inputs(plan=swarm.plan(), intents={4: Intent.QUIT}))
    assert result.over.reason is EndReason.GCS_QUIT and result.over.turn == 4
    records = result.records
    assert records[-2]["intent"] == "QUIT"
    config, autopilots = replay.header_config(records[0])
    assert replay.verify("q", records, config, autopilots) is None


def test_unscripted_gcs_runs_to_the_turn_limit(swarm: Scenario) -> None:
    result = run(swarm, Inputs(plan=swarm.plan(), scripted=False))
    assert result.over.reason is EndReason.TURN_LIMIT and result.over.turn == swarm.max_turns
