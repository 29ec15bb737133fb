"""Cells <-> local NED metres <-> WGS84, for the MAVLink vehicles (docs/mavlink.md, Coordinates).

Local NED has its origin at cell (0, 0, 0): north = x * cell size, east = y * cell size, down = -z * cell size.
WGS84 places that origin at `origin` (latitude, longitude in degrees, altitude in metres above mean sea
level) and goes from metres to degrees on a sphere of the WGS84 equatorial radius, flat around the origin
(an equirectangular projection: exact enough for worlds of a few kilometres, and it maps back to the same
cell). A position given back is rounded to the nearest cell; one that is not a finite number is refused."""

from __future__ import annotations

import math
from dataclasses import dataclass

from schema import Cell, UsageError
from world.grid import CELL_SIZE_M

#: WGS84's equatorial radius (metres).
EARTH_RADIUS = 6_378_137.0

#: The documented default origin: PX4's simulation home (Zurich), so that maps and tools show the usual place.
DEFAULT_ORIGIN = (47.397742, 8.545594, 488.0)


class BadPosition(ValueError):
    """A position that is not a finite number, or that no cell of any world could be."""


def _finite(*values: float) -> None:
    if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
        raise BadPosition(f"not a finite position: {', '.join(repr(v) for v in values)}")


@dataclass(frozen=True, slots=True, kw_only=True)
class Geo:
    """The mapping of one game: `cell_size` metres a cell, the WGS84 `origin` of cell (0, 0, 0)."""

    cell_size: float = CELL_SIZE_M
    origin: tuple[float, float, float] = DEFAULT_ORIGIN

    def __post_init__(self) -> None:
        if not (isinstance(self.cell_size, (int, float)) and math.isfinite(self.cell_size) and self.cell_size > 0):
            raise UsageError(f"the cell size must be a positive number of metres, got {self.cell_size!r}")
        lat, lon, alt = self.origin
        if not all(math.isfinite(v) for v in self.origin) or not (-85 <= lat <= 85 and -180 <= lon <= 180):
            raise UsageError(f"the origin must be LAT,LON,ALT with |LAT| <= 85 and |LON| <= 180, got {self.origin}")

    @classmethod
    def parse_origin(cls, text: str) -> tuple[float, float, float]:
        """``LAT,LON,ALT`` (degrees, degrees, metres above mean sea level)."""
        try:
            lat, lon, alt = (float(p) for p in text.split(","))
        except ValueError:
            raise UsageError(f"--origin {text!r}: expected LAT,LON,ALT (degrees, degrees, metres)") from None
        return (lat, lon, alt)

    @property
    def _per_degree(self) -> tuple[float, float]:
        """Metres a degree of latitude and of longitude, at the origin."""
        north = EARTH_RADIUS * math.pi / 180
        return north, north * math.cos(math.radians(self.origin[0]))

    # cells -> the vehicles' telemetry

    def ned(self, cell: Cell) -> tuple[float, float, float]:
        """Local NED metres of a cell's centre."""
        s = self.cell_size
        return cell[0] * s, cell[1] * s, -cell[2] * s

    def amsl(self, z: int) -> float:
        """Altitude above mean sea level (metres) of floor `z`."""
        return self.origin[2] + z * self.cell_size

    def wgs84(self, cell: Cell) -> tuple[float, float, float]:
        """(latitude, longitude, altitude above mean sea level) of a cell's centre."""
        north, east, _ = self.ned(cell)
        per_lat, per_lon = self._per_degree
        return self.origin[0] + north / per_lat, self.origin[1] + east / per_lon, self.amsl(cell[2])

    # positions given by a client -> cells (rounded; refused if not finite)

    def floor_of(self, altitude: float) -> int:
        """The floor nearest to an altitude above mean sea level (metres)."""
        _finite(altitude)
        return _round((altitude - self.origin[2]) / self.cell_size)

    def cell_of_ned(self, north: float, east: float, down: float) -> Cell:
        _finite(north, east, down)
        s = self.cell_size
        return _round(north / s), _round(east / s), _round(-down / s)

    def cell_of_wgs84(self, lat: float, lon: float, altitude: float) -> Cell:
        """The cell nearest to a WGS84 position (altitude above mean sea level)."""
        _finite(lat, lon, altitude)
        if not (-90 <= lat <= 90 and -180 <= lon <= 180):
            raise BadPosition(f"latitude {lat} or longitude {lon} out of range")
        per_lat, per_lon = self._per_degree
        dlon = (lon - self.origin[1] + 180) % 360 - 180
        return (_round((lat - self.origin[0]) * per_lat / self.cell_size),
                _round(dlon * per_lon / self.cell_size), self.floor_of(altitude))


#: Beyond this many cells from the origin no world reaches (schema cells are far smaller): refused as such.
_FAR = 1 << 30


def _round(v: float) -> int:
    if abs(v) > _FAR:
        raise BadPosition(f"{v:g} cells from the origin: no world is that large")
    return math.floor(v + 0.5)
