"""`dronesim bench rl --quick`: the table has a safe and a random row at each count, both backends for the
safe policy, which kills no drone (every step has all its agents), and the random policy's episodes (resets).
Behaviour only: no wall-clock assertion."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks import BENCHMARKS, rl
from dronesim.rl import Seen

pytestmark = pytest.mark.integration


def test_quick_run_writes_the_table(capsys, tmp_path):
    assert BENCHMARKS["rl"] == "rl"
    out_file = tmp_path / "BENCHMARKS.md"
    out_file.write_text("# Benchmarks\n\n## Performance\n\nkept\n", encoding="utf-8")
    assert rl.main(["--quick", "--no-pogema", "--write", "--output", str(out_file)]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("| ")]
    head = [c.strip() for c in lines[0].strip("|").split("|")]
    rows = {(cells[0], cells[1]): dict(zip(head, cells)) for cells in
            ([c.strip() for c in ln.strip("|").split("|")] for ln in lines[1:])}
    assert set(rows) == {(n, p) for n in ("1", "16") for p in ("safe", "random")}
    for (n, policy), row in rows.items():
        assert float(row["local steps/s"]) > 0
        end = row["agents acting at the end (local / zenoh); episodes"]
        if policy == "safe":  # the safe policy kills no drone: every step has all its agents
            assert float(row["zenoh steps/s"]) > 0 and end == f"{n} / {n} of {n}"
        else:  # uniformly random actions: drones die, episodes end and are reset (each slice starts one)
            assert row["zenoh steps/s"] == "—" and int(end.split()[0]) >= rl.SLICES
        assert row["target"].startswith("not judged")  # no POGEMA, no verdict
    text = out_file.read_text(encoding="utf-8")
    assert "## Performance\n\nkept" in text and "## RL environment" in text
    assert "`dronesim bench rl --quick --no-pogema --write --output" in text


def test_safe_random_never_picks_a_deadly_move():
    radius = 2
    policy = rl.SafeRandom(radius, seed=3)
    side = 2 * radius + 1
    rng = np.random.default_rng(0)
    obs = rng.integers(0, 5, size=(500, side ** 3 + 3)).astype(np.int32)
    obs[:, side ** 3 // 2] = Seen.FREE
    chosen = policy(obs)
    assert set(chosen.tolist()) <= set(range(7)) and (chosen == 0).any() and (chosen > 0).any()
    for o, a in zip(obs, chosen.tolist()):
        if a:
            assert o[policy.cell[a - 1]] == Seen.FREE
            assert (o[policy.around[a - 1]] != Seen.DRONE).all()


def test_pogema_pettingzoo_integration_is_measured():
    from benchmarks import pogema

    try:
        pogema.python()
    except pogema.Unavailable as exc:  # no venv module or no package index here: say so (pytest -rs)
        pytest.skip(f"POGEMA cannot be installed here: {exc}")
    rates = pogema.parallel_steps_per_second([1, 16], seconds=0.2)
    assert set(rates) == {1, 16} and all(v > 0 for v in rates.values())
