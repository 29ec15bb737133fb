"""The web ground station in headless Chromium: a real simulation (router, coordinator, environment, a
drone, the web GCS, each a process), a target set by clicking a cell, the drone seen arriving, invalid
input refused with a message, a death with its cause, a journal replayed. Every wait is on the page's
DOM or on a process's output, never a sleep. Screenshots go to artifacts/."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest

from entities.environment import build_world
from schema import WorldSpec
from tests.e2e.conftest import fly_to_clicked_cell
from tests.harness import Cluster, Proc, embedded_router, journal_records
from tests.test_web_gcs import write_journal
from world.grid import Building, World

pytestmark = pytest.mark.integration

URL = re.compile(r"web ground station: (http://\S+)")


@pytest.fixture
def cluster(tmp_path):
    with embedded_router() as locator, Cluster(locator, tmp_path) as c:
        yield c


def start_web_game(c: Cluster, tmp_path, *, coord: tuple, autopilot: str, gcs: tuple = ()) -> tuple[str, object]:
    journal = tmp_path / "web.journal"
    srv = c.start("SRV", "coordinator", "--journal", str(journal), "--admit-deadline", "60", *coord)
    srv.expect("coordinator ready")
    c.start("ENV", "env", "--no-draw")
    c.start("D01", "drone", "--id", "D01", "--autopilot", autopilot)
    web = c.start("GCS", "gcs", "--web", "127.0.0.1:0", *gcs)
    return URL.search(web.expect(URL.pattern)).group(1), journal


def test_click_a_cell_and_watch_the_drone_arrive(cluster, tmp_path, page, artifacts):
    url, journal = start_web_game(cluster, tmp_path, coord=("--seed", "7"), autopilot="seed", gcs=("--pace", "0.05"))
    page.goto(url)
    page.wait_for_selector("#conn[data-state=live]")
    page.wait_for_function("document.querySelector('#gamestate').textContent.includes('first target')")
    assert page.inner_text("#mode") == "LIVE"
    assert page.locator("#grid .cell").count() == 100
    assert page.locator("#floors button").count() == 10
    assert page.get_attribute("#drone-D01 [data-status]", "data-status") == "alive"

    # invalid input is refused in the page, with a clear message
    page.fill("#target-input", "10,0,0")
    page.click("#target-set")
    page.wait_for_selector("#message.error")
    assert "outside the world: 0 <= x < 10" in page.inner_text("#message")
    page.fill("#target-input", "3,4")
    page.click("#target-set")
    page.wait_for_function("document.querySelector('#message').textContent.includes('is not x,y,z')")
    x, y, z = (int(v) for v in np.argwhere(build_world(WorldSpec(size=(10, 10, 10), seed=7), [(0, 0, 0)]).grid)[0])
    page.fill("#target-input", f"{x},{y},{z}")
    page.click("#target-set")
    page.wait_for_function("document.querySelector('#message').textContent.includes('inside a building')")
    # ... and by the server too, whatever the page lets through
    refused = page.evaluate("""async ([x, y, z]) => {
        const post = (body) => fetch('/api/target', {method: 'POST', headers: {'Content-Type': 'application/json'},
                                                    body: JSON.stringify(body)});
        const unknown = await post({drone: 'D07', cell: [1, 1, 0]});
        const building = await post({drone: 'D01', cell: [x, y, z]});
        return [unknown.status, (await unknown.json()).error, building.status, (await building.json()).error];
    }""", [x, y, z])
    assert refused == [422, "unknown drone D07: this game flies D01",
                       422, f"({x}, {y}, {z}) is inside a building: no drone can get there"]
    assert page.get_attribute("#drone-D01 [data-status]", "data-status") == "alive"

    # pick the floor, click the cell: the drone flies there
    fly_to_clicked_cell(page, "D01", (9, 9, 0))
    page.wait_for_function("document.querySelector('#gamestate').textContent.includes('at its target')")
    assert "D01" in page.inner_text("#grid .cell[data-x='9'][data-y='9']")
    assert page.locator("#grid .cell.trail").count() >= 10
    assert "D01 reached its target (9, 9, 0)" in page.inner_text("#log")
    turn = int(page.inner_text("#turn"))
    assert turn >= 18
    page.screenshot(path=str(artifacts / "web-gcs-live.png"), full_page=True)

    # a reload gets the whole current state at once
    page.reload()
    page.wait_for_selector("#drone-D01 [data-status=reached]")
    assert int(page.inner_text("#turn")) == turn
    assert "D01 reached its target (9, 9, 0)" in page.inner_text("#log")

    # quit: OVER reaches the page, every process exits 0
    page.click("#quit")
    page.click("#quit-yes")
    page.wait_for_selector("#over:not([hidden])")
    assert "GCS_QUIT" in page.inner_text("#over")
    page.wait_for_selector("#conn[data-state=ended]")
    assert page.is_disabled("#target-set")
    page.screenshot(path=str(artifacts / "web-gcs-over.png"), full_page=True)
    assert set(cluster.wait_all().values()) == {0}, [p.text for p in cluster.procs]
    records = journal_records(journal)
    assert records[-1]["reason"] == "GCS_QUIT" and records[1]["targets"] == {"D01": [9, 9, 0]}


def test_a_crash_shows_its_cause_and_game_over(cluster, tmp_path, page, artifacts):
    world = tmp_path / "wall.json"
    World.from_buildings((6, 6, 2), [Building(x=2, y=0, length=1, width=6, height=1)]).save(world)
    url, _ = start_web_game(cluster, tmp_path, coord=("--world", str(world)), autopilot="v1", gcs=("--pace", "0"))
    page.goto(url)
    page.wait_for_selector("#conn[data-state=live]")
    page.fill("#target-input", "5,0,0")
    page.press("#target-input", "Enter")
    page.wait_for_selector("#over:not([hidden])")
    assert "NO_DRONE_ALIVE" in page.inner_text("#over")
    page.wait_for_selector("#drone-D01 [data-status=dead]")
    assert "D01 died at (2, 0, 0): crashed into a building" in page.inner_text("#log")
    assert page.inner_text("#grid .cell[data-x='2'][data-y='0']") == "D01"
    page.screenshot(path=str(artifacts / "web-gcs-crash.png"), full_page=True)
    assert set(cluster.wait_all().values()) == {0}, [p.text for p in cluster.procs]


def test_replay_plays_a_journal(tmp_path, page, artifacts):
    journal = tmp_path / "two.journal"
    world = World.generate((8, 8, 4), 3, keep_free=((0, 0, 0), (0, 7, 1)))
    records = write_journal(journal, world, {"D01": (0, 0, 0), "D02": (0, 7, 1)}, {"D01": "dstar", "D02": "dstar"},
                            ["D01=7,7,0", "D02=7,0,2@3"])
    last = records[-1]["turn"]
    proc = Proc("replay", [sys.executable, "-m", "dronesim", "gcs", "--web", "127.0.0.1:0", "--replay", str(journal)],
                tmp_path)
    try:
        url = URL.search(proc.expect(URL.pattern)).group(1)
        page.goto(url)
        page.wait_for_selector("#replay-controls:not([hidden])")
        assert page.inner_text("#mode") == "REPLAY"
        assert page.is_hidden("#target-panel") and page.is_hidden("#live-controls")
        assert page.inner_text("#turn") == "0"
        page.click("#rp-fwd")
        page.wait_for_function("document.querySelector('#turn').textContent === '1'")
        page.click("#rp-end")
        page.wait_for_function(f"document.querySelector('#turn').textContent === '{last}'")
        assert records[-1]["reason"] in page.inner_text("#over")
        assert page.get_attribute("#drone-D01 [data-status]", "data-status") == "reached"
        page.click("#rp-back")
        page.wait_for_function(f"document.querySelector('#turn').textContent === '{last - 1}'")
        assert page.is_hidden("#over")
        page.select_option("#rp-speed", "40")
        page.click("#rp-start")
        page.click("#rp-play")  # plays to the end by itself
        page.wait_for_function(f"document.querySelector('#turn').textContent === '{last}'")
        page.wait_for_function("document.querySelector('#rp-play').textContent.includes('play')")
        page.click("#grid .cell[data-x='1'][data-y='1']")  # read only
        assert "replay" in page.inner_text("#message")
        page.click("#rot-right")
        page.screenshot(path=str(artifacts / "web-gcs-replay.png"), full_page=True)
    finally:
        proc.p.terminate()  # a replay serves until stopped: stopped cleanly, with SIGTERM's status
        assert proc.wait() == 143, proc.text


def test_replay_of_a_bad_journal_is_a_clear_error(tmp_path):
    bad = tmp_path / "bad.journal"
    bad.write_text("hello\n")
    p = subprocess.run([sys.executable, "-m", "dronesim", "gcs", "--web", "127.0.0.1:0", "--replay", str(bad)],
                       capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
    assert p.returncode == 2 and "not a journal record" in p.stderr
