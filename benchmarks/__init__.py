"""Benchmarks: ``dronesim bench NAME [options]`` (or ``python -m benchmarks.NAME``); results in BENCHMARKS.md."""

from __future__ import annotations

import argparse
import datetime
import importlib
import os
import platform
import re
import shlex
import sys
from pathlib import Path

#: benchmark name -> module (each has ``main(argv) -> int``).
BENCHMARKS = {"autopilot": "autopilot", "callbacks": "callbacks", "compiled-scatter": "compiled_scatter",
              "export": "export", "flood": "flood", "instructions": "instructions", "lifelong": "lifelong",
              "perf": "perf", "rl": "rl", "swarm": "swarm", "versus": "versus"}


def cli(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in BENCHMARKS:
        lines = [f"usage: dronesim bench {{{','.join(BENCHMARKS)}}} [options]   (dronesim bench NAME --help)", ""]
        for name, module in BENCHMARKS.items():
            doc = (importlib.import_module(f"{__name__}.{module}").__doc__ or "").strip().splitlines()
            lines.append(f"  {name:<10} {doc[0] if doc else ''}")
        asked = argv[:1] in (["-h"], ["--help"])
        print("\n".join(lines), file=sys.stdout if asked else sys.stderr)
        return 0 if asked else 2
    return int(importlib.import_module(f"{__name__}.{BENCHMARKS[argv[0]]}").main(argv[1:]) or 0)


def replace_section(path: Path, title: str, body: str, keep: str | tuple[str, ...] | None = None) -> None:
    """Replace (or append) the section `title` ("## ...") of a Markdown file, leaving the others alone (and its
    subsections `keep` ("### ..."), those it has: other commands')."""
    text = path.read_text(encoding="utf-8") if path.exists() else "# Benchmarks\n"
    subs = (keep,) if isinstance(keep, str) else keep or ()
    kept = [k for k in (_subsection(text, title, sub) for sub in subs) if k]
    section = f"{title}\n\n{body.strip()}\n" + "".join(f"\n{k.strip()}\n" for k in kept)
    pattern = re.compile(rf"^{re.escape(title)}[ \t]*\n.*?(?=^## |\Z)", re.S | re.M)
    if pattern.search(text):
        text = pattern.sub(lambda _: section + "\n", text, count=1).rstrip("\n") + "\n"
    else:
        text = text.rstrip("\n") + "\n\n" + section
    path.write_text(text, encoding="utf-8")


def _subsection(text: str, title: str, sub: str) -> str | None:
    """The subsection `sub` ("### ...", up to the next heading of level 2 or 3) of section `title`, if any."""
    section = re.search(rf"^{re.escape(title)}[ \t]*\n.*?(?=^## |\Z)", text, re.S | re.M)
    if section is None:
        return None
    found = re.search(rf"^{re.escape(sub)}[ \t]*\n.*?(?=^##+ |\Z)", section.group(0), re.S | re.M)
    return found.group(0) if found else None


def replace_subsection(path: Path, title: str, sub: str, body: str) -> None:
    """Replace (or append at the end of section `title`, made if need be) its subsection `sub` ("### ...")."""
    text = path.read_text(encoding="utf-8") if path.exists() else "# Benchmarks\n"
    if not re.search(rf"^{re.escape(title)}[ \t]*$", text, re.M):
        text = text.rstrip("\n") + f"\n\n{title}\n"
    old = _subsection(text, title, sub)
    section = re.search(rf"^{re.escape(title)}[ \t]*\n.*?(?=^## |\Z)", text, re.S | re.M)
    assert section is not None
    part = section.group(0)
    new = f"{sub}\n\n{body.strip()}\n\n"
    part = part.replace(old, new, 1) if old else part.rstrip("\n") + f"\n\n{new}"
    text = text[:section.start()] + part + text[section.end():]
    path.write_text(text.rstrip("\n") + "\n", encoding="utf-8")


def add_write_args(parser: argparse.ArgumentParser) -> None:
    """--write / --output: record a benchmark's table in its section of BENCHMARKS.md."""
    parser.add_argument("--write", action="store_true", help="update the section in BENCHMARKS.md")
    parser.add_argument("--output", type=Path, default=Path(__file__).resolve().parent.parent / "BENCHMARKS.md",
                        help="file --write updates (default: the repository's BENCHMARKS.md)")


def command_line(name: str, argv: list[str] | None, seconds: float) -> str:
    """The first line of a recorded table: the command that made it (`argv`, default the process's), when, on
    what, and how long it took."""
    args = " ".join(shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
    command = f"dronesim bench {name} {args}".strip()
    return (f"Command: `{command}`, run "
            f"{datetime.date.today().isoformat()} on {platform.machine()} with nproc = {os.cpu_count()} "
            f"(Python {platform.python_version()}), {seconds:.0f} s in all.")
