"""The generated docs are up to date, and the README's commands are the ones CI runs."""

from __future__ import annotations

import pathlib

from schema import doc

ROOT = pathlib.Path(__file__).resolve().parent.parent


def test_schema_readme_is_generated_from_the_schema():
    assert (ROOT / "schema" / "README.md").read_text() == doc.render(), \
        "schema/README.md is stale: run python -m schema.doc --write"


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    assert "bash tests/run.sh" in readme
    assert "exec bash tests/run.sh" in (ROOT / ".ci" / "run").read_text()
