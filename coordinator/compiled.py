"""The scattered paths' search compiled (coordinator/scatter.c), where this machine can: built once by the system's C
compiler into the user's cache and loaded through ctypes. `lacam.Scatter` runs it where `scatter_library` gives one
and its own Python otherwise: the same paths and work units either way (the C file is `Scatter`'s search step for
step), so a game's decisions, its journal, replay and resume never depend on which ran; only the time does
(docs/cooperation.md, "Scattered paths"; docs/performance.md). The same library holds the exact search's joint moves
(`exact.Exact._successors`, `ex_successors`): the same configurations, in the same order, as its Python.

`DRONESIM_COMPILED=0` in the environment turns it off (Python's alone). A library is built where the source's hash
names it, in `$XDG_CACHE_HOME/dronesim` (else ~/.cache/dronesim), a folder of this user's that nobody else may write;
where there is none, in a temporary folder of this process's. No compiler, a failed build or a library that does not
load: None, said once in the log."""

from __future__ import annotations

import ctypes
import functools
import hashlib
import logging
import os
import shutil
import stat
import subprocess
import tempfile
from importlib import resources
from pathlib import Path

__all__ = ["scatter_library", "ENV"]

#: The environment variable that turns the compiled search off ("0").
ENV = "DRONESIM_COMPILED"

_LOG = logging.getLogger("dronesim.compiled")


def _cache() -> Path | None:
    """This user's cache folder for dronesim's libraries, made private; None where it cannot be (another's, or
    others may write it)."""
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "dronesim"
    try:
        base.mkdir(parents=True, exist_ok=True, mode=0o700)
        info = base.stat()
    except OSError:
        return None
    if info.st_uid != os.getuid() or info.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return None
    return base


def _build(source: bytes, folder: Path, name: str) -> Path:
    """`source` compiled into `folder`/`name` (written under another name, then renamed: a library is whole or
    absent); RuntimeError if there is no compiler or it fails."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise RuntimeError("no C compiler (cc, gcc) on the PATH")
    with tempfile.TemporaryDirectory(dir=folder, prefix=".build-") as tmp:
        src, lib = Path(tmp) / "scatter.c", Path(tmp) / name
        src.write_bytes(source)
        done = subprocess.run([cc, "-O2", "-shared", "-fPIC", "-o", str(lib), str(src)], capture_output=True,
                              text=True, timeout=120, stdin=subprocess.DEVNULL)
        if done.returncode != 0:
            raise RuntimeError(f"{cc} failed: {done.stderr.strip()[:500]}")
        os.replace(lib, folder / name)
    return folder / name


def _typed(lib: ctypes.CDLL) -> ctypes.CDLL:
    i64, ptr = ctypes.c_int64, ctypes.c_void_p
    lib.sc_new.argtypes, lib.sc_new.restype = [i64, i64, i64, i64, ptr, ptr, i64], ptr
    lib.sc_plan.argtypes, lib.sc_plan.restype = [ptr, i64, i64, i64], i64
    lib.sc_collisions.argtypes, lib.sc_collisions.restype = [ptr], i64
    lib.sc_path_length.argtypes, lib.sc_path_length.restype = [ptr, i64], i64
    lib.sc_path_cells.argtypes, lib.sc_path_cells.restype = [ptr, i64, ptr], None
    lib.sc_free.argtypes, lib.sc_free.restype = [ptr], None
    lib.ex_successors.argtypes, lib.ex_successors.restype = [i64, i64, ptr, i64, ptr, ptr, ptr, ptr, i64], i64
    return lib


@functools.cache
def scatter_library() -> ctypes.CDLL | None:
    """The compiled scattered paths' search (coordinator/scatter.c), built on first use where it is not yet; None
    where it is turned off (`ENV`) or cannot be had."""
    if os.environ.get(ENV, "1") == "0":
        return None
    try:
        source = resources.files("coordinator").joinpath("scatter.c").read_bytes()
        name = f"scatter-{hashlib.sha256(source).hexdigest()[:16]}.so"
        folder = _cache()
        if folder is not None and (folder / name).is_file():
            try:
                return _typed(ctypes.CDLL(str(folder / name)))
            except (OSError, AttributeError) as exc:  # (not a library of ours: built again in its place)
                _LOG.info("the cached %s does not load (%s): built again", folder / name, exc)
        if folder is None:
            folder = Path(tempfile.mkdtemp(prefix="dronesim-"))
        return _typed(ctypes.CDLL(str(_build(source, folder, name))))
    except (OSError, RuntimeError, subprocess.SubprocessError, AttributeError) as exc:
        _LOG.info("the scattered paths' search runs in Python: %s", exc)
        return None
