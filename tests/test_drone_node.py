"""The drone process's pure parts: how it reads the environment's answers."""

from __future__ import annotations

import pytest


def test_survey_is_the_answer_as_a_mapping() -> None:
    """A drone host reads an ANS (with `around` cells) as {cell: CellInfo}, exactly as the environment
    would answer each cell."""
    import numpy as np

    from dronesim.entities.drone_node import Survey
    from dronesim.entities.environment import Environment
    from dronesim.entities.world import World
    from dronesim.schema import Ans, Ask

    e = Environment(World.generate((6, 6, 4), np.random.default_rng(2)), {"D01": (1, 1, 1), "D02": (2, 1, 1)})
    ask = Ask(turn=3, sender="H01", cells=((5, 5, 3), (9, 9, 9)), around=((1, 1, 1), (2, 1, 1), (0, 0, 0)))
    kinds, drones = e.survey(ask.cells, ask.around)
    survey = Survey(Ans(turn=3, sender="ENV", kinds=kinds, drones=drones), ask)
    asked = ask.asked()
    assert {c: survey[c] for c in asked} == dict(zip(asked, e.answer(asked)))
    assert survey[(2, 1, 1)].drones == ("D02",) and survey[(0, -1, 0)].kind.name == "OUTSIDE"
    assert (3, 3, 3) not in survey and "x" not in survey and set(survey) == set(asked) and len(survey) == len(set(asked))
    with pytest.raises(KeyError):
        survey[(3, 3, 3)]
