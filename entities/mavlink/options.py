"""The MAVLink ground station's flags (shared by ``dronesim gcs`` and ``dronesim up``; no pymavlink needed)."""

from __future__ import annotations

import argparse

from schema import UsageError
from schema.tuning import MAVLINK_PERIOD
from world.grid import CELL_SIZE_M

from .geo import DEFAULT_ORIGIN

#: The flags' names (as `argparse` stores them), for a command that passes them on.
MAVLINK_FLAGS = ("mavlink", "mavlink_gcs", "mavlink_api_base", "cell_size", "origin", "turn_period")


def add_mavlink_args(parser: argparse.ArgumentParser, *, cell_size: bool = True) -> None:
    """The flags; `cell_size` False where the parser has ``--cell-size`` already (the ROS 2 flags': one meaning)."""
    g = parser.add_argument_group("MAVLink ground station (docs/mavlink.md)")
    g.add_argument("--mavlink", action="store_true",
                   help="every drone a MAVLink vehicle (system n for Dnn) for QGroundControl, MAVProxy, MAVSDK")
    g.add_argument("--mavlink-gcs", default="udpout:127.0.0.1:14550", metavar="udpout:HOST:PORT",
                   help="where the fleet sends to the ground station (default udpout:127.0.0.1:14550)")
    g.add_argument("--mavlink-api-base", type=int, default=14540, metavar="PORT",
                   help="vehicle n sends to an API client on UDP PORT + n - 1 (default 14540, as PX4)")
    if cell_size:
        g.add_argument("--cell-size", type=float, default=CELL_SIZE_M, metavar="METRES",
                       help=f"metres a cell (default {CELL_SIZE_M})")
    g.add_argument("--origin", default=",".join(map(repr, DEFAULT_ORIGIN)), metavar="LAT,LON,ALT",
                   help="WGS84 position of cell (0,0,0): degrees, degrees, metres above sea level "
                        "(default %(default)s, PX4's simulation home)")
    g.add_argument("--turn-period", type=float, default=MAVLINK_PERIOD, metavar="SECONDS",
                   help=f"a turn every SECONDS, so that a cell a turn reads as a speed (default {MAVLINK_PERIOD:g}: "
                        f"{1 / MAVLINK_PERIOD:g} cells a second)")


def parse_udpout(text: str) -> tuple[str, int]:
    """``udpout:HOST:PORT`` (as pymavlink and MAVProxy write it)."""
    kind, _, rest = text.partition(":")
    host, _, port = rest.rpartition(":")
    if kind != "udpout" or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise UsageError(f"--mavlink-gcs {text!r}: expected udpout:HOST:PORT")
    return host, int(port)
