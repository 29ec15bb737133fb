"""The folders are floors (README, Layout): each imports only the floors under it, and no modules import each other in
a circle. Read from the code's imports (every one, a function's too), not from running it."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: Each folder's floor: a module may import its own folder's and those of lower floors, nothing else of ours.
FLOORS = {"schema": 1, "world": 2, "network": 2, "coordinator": 3, "docker": 3, "entities": 4, "dronesim": 5,
          "benchmarks": 6}


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path) -> set[str]:
    """The modules of ours that `path` imports, by their full names (relative imports resolved)."""
    package = module_name(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = ".".join([*package[:len(package) - node.level + 1], *([node.module] if node.module else [])]) \
                if node.level else node.module or ""
            out |= {f"{base}.{a.name}" for a in node.names}  # (a module, or a name of `base`'s)
    return {m for m in out if m.split(".")[0] in FLOORS}


def sources() -> dict[str, Path]:
    return {module_name(p): p for folder in FLOORS for p in (ROOT / folder).rglob("*.py")
            if "__pycache__" not in p.parts}


def test_no_import_runs_back_up_or_across_a_floor() -> None:
    up = []
    for name, path in sources().items():
        mine = name.split(".")[0]
        for target in imports(path):
            theirs = target.split(".")[0]
            if theirs != mine and FLOORS[theirs] >= FLOORS[mine]:
                up.append(f"{name} -> {target}")
    assert not up, "imports that run back up (or across a floor): " + ", ".join(sorted(up))


def test_no_modules_import_each_other_in_a_circle() -> None:
    known = sources()
    graph = {}
    for name, path in known.items():
        # a name imported from a package is its module if there is one, else the package's __init__ (a package's
        # __init__ that runs before any of its modules is no import of theirs)
        graph[name] = {t if t in known else t.rsplit(".", 1)[0] for t in imports(path)} & known.keys() - {name}
    state: dict[str, int] = {}  # 1: on the path being walked, 2: done
    circles = []

    def walk(node: str, path: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                circles.append(" -> ".join(path[path.index(nxt):] + [nxt]))
            elif nxt not in state:
                walk(nxt, path + [nxt])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            walk(node, [node])
    assert not circles, "modules importing each other: " + "; ".join(circles)
