"""The scattered paths' search compiled (coordinator/scatter.c), where this machine can: built once by the system's C
compiler into the user's cache and loaded through ctypes. `lacam.Scatter` runs it where `scatter_library` gives one
and its own Python otherwise: the same paths and work units either way (the C file is `Scatter`'s search step for
step), so a game's decisions, its journal, replay and resume never depend on which ran; only the time does
(docs/cooperation.md, "Scattered paths"; docs/performance.md). The same library holds the exact search's joint moves
(`exact.Exact._successors`, `ex_successors`): the same configurations, in the same order, as its Python.

`DRONESIM_COMPILED=0` in the environment turns it off (Python's alone). A library is named by the source's hash. One
shipped in the package's own folder (`SHIPPED`: the Docker image's, put there at its build by `ship`, for its runtime
has no C compiler) is loaded first; else one is built in `$XDG_CACHE_HOME/dronesim` (else ~/.cache/dronesim), a folder
of this user's that nobody else may write; where there is none, in a temporary folder of this process's. No compiler,
a failed build or a library that does not load: None, said once in the log.

`python -m coordinator.compiled --build DIR` builds the library into DIR with this machine's C compiler
(docker/offline.sh, on the host, into the wheelhouse); `--ship DIR` puts DIR's library for this source (else one built
here) in the package's folder if it loads here (docker/Dockerfile's build stage)."""

from __future__ import annotations

import argparse
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

__all__ = ["scatter_library", "ENV", "SHIPPED", "ship"]

#: The environment variable that turns the compiled search off ("0").
ENV = "DRONESIM_COMPILED"

_LOG = logging.getLogger("dronesim.compiled")
#: The package's own folder, where an image's build puts the library (`ship`): as trusted as the code beside it.
SHIPPED = Path(__file__).resolve().parent


def _source() -> tuple[bytes, str]:
    """coordinator/scatter.c and its library's name (the source's hash: a library is never another source's)."""
    source = resources.files("coordinator").joinpath("scatter.c").read_bytes()
    return source, f"scatter-{hashlib.sha256(source).hexdigest()[:16]}.so"


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
    lib.sc_free.argtypes, lib.sc_free.restype = [ptr], None
    lib.sc_paths_length.argtypes, lib.sc_paths_length.restype = [ptr], i64
    lib.sc_paths.argtypes, lib.sc_paths.restype = [ptr, ptr, ptr], None
    lib.ex_successors.argtypes, lib.ex_successors.restype = [i64, i64, ptr, i64, ptr, ptr, ptr, ptr, i64], i64
    lib.pb_pibt.argtypes = [i64, i64, ptr, ptr, ptr, i64, ptr, ctypes.c_char_p, i64, ptr, i64, ptr, ptr, i64, i64, ptr]
    lib.pb_pibt.restype = i64
    lib.pb_candidates.argtypes = [i64, i64, ptr, ptr, ptr, i64, ptr, ptr, ptr, i64, ctypes.c_uint64, i64, i64, i64,
                                  ptr, ptr]
    lib.pb_candidates.restype = i64
    lib.pb_choosers.argtypes, lib.pb_choosers.restype = [i64, i64, ptr, ptr, ptr, ptr, i64, ptr], i64
    lib.pb_valid.argtypes, lib.pb_valid.restype = [i64, ptr, ptr, i64], i64
    return lib


@functools.cache
def scatter_library() -> ctypes.CDLL | None:
    """The compiled scattered paths' search (coordinator/scatter.c), built on first use where it is not yet; None
    where it is turned off (`ENV`) or cannot be had."""
    if os.environ.get(ENV, "1") == "0":
        return None
    try:
        source, name = _source()
        if (SHIPPED / name).is_file():
            try:
                return _typed(ctypes.CDLL(str(SHIPPED / name)))
            except (OSError, AttributeError) as exc:  # (another machine's: built here instead)
                _LOG.info("the shipped %s does not load (%s)", SHIPPED / name, exc)
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


def ship(folder: Path, into: Path) -> Path | None:
    """This source's library from `folder` (docker/offline.sh builds it there on the host), else one built now,
    copied into `into` (the package's folder, `SHIPPED`) if it loads in this process (a host's library may need a
    newer C library than the image's); None where there is none (said why: the search then runs in Python)."""
    source, name = _source()
    made = folder / name
    with tempfile.TemporaryDirectory(prefix="dronesim-ship-") as tmp:
        try:
            if not made.is_file():
                made = _build(source, Path(tmp), name)
            shutil.copyfile(made, into / f".{name}.part")
            _typed(ctypes.CDLL(str(into / f".{name}.part")))
        except (OSError, RuntimeError, subprocess.SubprocessError, AttributeError) as exc:
            (into / f".{name}.part").unlink(missing_ok=True)
            print(f"compiled: no library shipped ({exc}): the search runs in Python (the same games, slower)")
            return None
    os.replace(into / f".{name}.part", into / name)
    print(f"compiled: shipped {into / name}")
    return into / name


def main(argv: list[str] | None = None) -> int:
    """`--build DIR` / `--ship DIR` (the module's doc). Exit 0 whether or not a library is had: without one the
    search runs in Python, the same games (a build that cannot find a compiler says so and goes on)."""
    parser = argparse.ArgumentParser(prog="python -m coordinator.compiled", description=__doc__.split("\n\n")[0])
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument("--build", type=Path, metavar="DIR", help="build the library into DIR (this machine's cc)")
    what.add_argument("--ship", type=Path, metavar="DIR",
                      help="put DIR's library (else one built here) in the package's folder if it loads")
    args = parser.parse_args(argv)
    if args.ship is not None:
        ship(args.ship, SHIPPED)
        return 0
    source, name = _source()
    try:
        args.build.mkdir(parents=True, exist_ok=True)
        for old in args.build.glob("scatter-*.so"):  # (an older source's: never loaded, but each a new build context)
            if old.name != name:
                old.unlink()
        if (args.build / name).is_file():
            print(f"compiled: {args.build / name} is there")  # (not built again: an image's build cache holds)
        else:
            print(f"compiled: built {_build(source, args.build, name)}")
    except (OSError, RuntimeError, subprocess.SubprocessError) as exc:
        print(f"compiled: not built ({exc}): an image built without it runs the search in Python")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
