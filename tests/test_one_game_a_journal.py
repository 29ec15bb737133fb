"""A journal holds one game (issue 33, item 2): a coordinator started on a journal that already holds one refuses
to start a new game on it (exit 2, saying what to do) and leaves it untouched; with --resume it resumes an
unfinished one. Before, it appended a second header and `dronesim replay --verify` failed on the result."""

from __future__ import annotations

import logging

import pytest

from coordinator.journal import dumps, held_game
from coordinator.node import build_parser, cli, game_config, open_game
from coordinator.stages import Stage
from dronesim.local import Inputs, simulate
from entities.gcs import Plan

FLAGS = ["--seed", "7", "--drones", "2", "--max-turns", "80"]
QUIET = logging.getLogger("test.one-game")


@pytest.fixture(scope="module")
def records() -> list[dict]:
    config = game_config(build_parser().parse_args(FLAGS))
    plan = Plan.parse(["D01=9,0,0", "D02=9,2,0"], config.world.size)
    result = simulate(config, {"D01": "dstar", "D02": "dstar"}, Inputs(plan=plan), QUIET)
    assert result.records[-1]["record"] == "over" and len(result.records) > 6
    return result.records


def write(path, records: list[dict]) -> bytes:
    data = "".join(dumps(r) + "\n" for r in records).encode()
    path.write_bytes(data)
    return data


def test_a_new_game_on_a_journal_holding_an_unfinished_one_is_refused_and_changes_nothing(tmp_path, records, caplog):
    journal = tmp_path / "game.jsonl"
    data = write(journal, records[:5])
    with caplog.at_level(logging.ERROR):
        assert cli([*FLAGS, "--journal", str(journal)]) == 2
    assert f"holds an unfinished game (its last turn {records[4]['turn']}): resume it with --resume" in caplog.text
    assert journal.read_bytes() == data


def test_a_new_game_on_a_journal_holding_a_finished_one_is_refused_and_changes_nothing(tmp_path, records, caplog):
    journal = tmp_path / "game.jsonl"
    data = write(journal, records)
    with caplog.at_level(logging.ERROR):
        assert cli([*FLAGS, "--journal", str(journal)]) == 2
        assert cli([*FLAGS, "--journal", str(journal), "--resume"]) == 2
    assert f"holds a finished game (over at turn {records[-1]['turn']}): give another --journal" in caplog.text
    assert "nothing to resume (a journal holds one game" in caplog.text
    assert journal.read_bytes() == data


def test_resume_takes_up_an_unfinished_journal_and_a_missing_or_empty_one_starts_a_new_game(tmp_path, records):
    config = game_config(build_parser().parse_args(FLAGS))
    journal = tmp_path / "game.jsonl"
    write(journal, records[:5])
    assert held_game(journal) == (False, records[4]["turn"])
    engine = open_game(config, str(journal), True, QUIET)
    assert (engine.stage, engine.turn) == (Stage.RESUMING, records[4]["turn"])
    for path in (tmp_path / "missing.jsonl", tmp_path / "empty.jsonl"):
        if path.name == "empty.jsonl":
            path.write_bytes(b"")
        assert held_game(path) is None
        assert open_game(config, str(path), False, QUIET).stage is Stage.ADMITTING
        assert open_game(config, str(path), True, QUIET).stage is Stage.ADMITTING


def test_a_journal_that_is_not_one_is_refused(tmp_path, caplog):
    journal = tmp_path / "notes.txt"
    journal.write_text("my notes\nmore notes\n")
    with caplog.at_level(logging.ERROR):
        assert cli([*FLAGS, "--journal", str(journal)]) == 2
    assert "not a journal record" in caplog.text
    assert journal.read_text() == "my notes\nmore notes\n"
