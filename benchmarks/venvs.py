"""A benchmark's anchor in a Python environment of its own (POGEMA, pymapf: what they pull in never meets the
project's), made in the user's cache on first use."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


class Unavailable(RuntimeError):
    """An anchor could not be installed or run here (the reason says why)."""


def venv_dir(name: str) -> Path:
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "dronesim" / name


def python(name: str, requirement: str, module: str) -> Path:
    """The interpreter of the environment `name` (a folder of the cache) holding `requirement`, made (and the
    requirement installed) on first use; `module` is what must import there. Unavailable if it cannot be made."""
    venv = venv_dir(name)
    exe = venv / "bin" / "python"
    if exe.exists() and subprocess.run([str(exe), "-c", f"import {module}"], capture_output=True).returncode == 0:
        return exe
    print(f"  {requirement}: installing into {venv} (once) ...", file=sys.stderr, flush=True)
    steps = ([sys.executable, "-m", "venv", "--clear", str(venv)],
             [str(exe), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", requirement])
    for cmd in steps:
        try:
            done = subprocess.run(cmd, capture_output=True, text=True, timeout=900, stdin=subprocess.DEVNULL)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise Unavailable(f"{cmd[2]} failed: {exc}") from None
        if done.returncode != 0:
            tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no output"]
            raise Unavailable(f"`{' '.join(cmd[-3:])}` exited {done.returncode}: {tail[0]}")
    return exe
