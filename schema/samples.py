"""The canonical sample of every message type, whose bytes are the golden test vectors.

``python -m schema.samples --write`` regenerates schema/vectors.json after a deliberate
change of the contract (bump SCHEMA_VERSION when the bytes of an existing message change).
"""

from __future__ import annotations

import argparse
import json
import pathlib

from . import messages as m
from .tables import rank_steps

VECTORS_PATH = pathlib.Path(__file__).with_name("vectors.json")

SAMPLES: dict[str, m.Message] = {
    "connect_env": m.Connect(turn=0, sender="ENV", role=m.Role.ENV),
    "connect_gcs": m.Connect(turn=0, sender="GCS", role=m.Role.GCS),
    "connect_drone": m.Connect(turn=0, sender="D01", role=m.Role.DRONE, drones=("D01",), autopilot="seed",
                               session="7f3a9c2e41b05d68"),
    "connect_swarm": m.Connect(turn=0, sender="H01", role=m.Role.DRONE, drones=("D01", "D02"), autopilot="dstar",
                               cooperative=True),
    "welcome": m.Welcome(turn=0, sender="SRV", entity="D01", text="You are connected as D01",
                         world=m.WorldSpec(size=(10, 10, 10), seed=7),
                         starts=m.StartTable.of([m.Start(drone="D01", pos=(0, 0, 0))]), game="9f2c4e1a7b3d5f60"),
    "welcome_file_world": m.Welcome(turn=0, sender="SRV", entity="ENV", text="You are connected as ENV",
                                    world=m.WorldSpec(size=(2, 2, 2), cells=bytes([0b10000000])),
                                    starts=m.StartTable.of([m.Start(drone="D01", pos=(0, 0, 1))])),
    "refused": m.Refused(turn=0, sender="SRV", text="role GCS is already taken"),
    "turn_gcs": m.Turn(turn=1, sender="SRV", phase=m.Phase.GCS),
    "turn_drones": m.Turn(turn=1, sender="SRV", phase=m.Phase.DRONES,
                          orders=m.OrderTable.of([m.Order(drone="D01", pos=(0, 0, 0), target=(9, 9, 0)),
                                                  m.Order(drone="D02", pos=(0, 1, 0))]), game="9f2c4e1a7b3d5f60"),
    "turn_env": m.Turn(turn=1, sender="SRV", phase=m.Phase.ENV,
                       moves=m.MoveTable.of([m.Move(drone="D01", src=(0, 0, 0), dst=(1, 0, 0)),
                                             m.Move(drone="D02", src=(0, 1, 0), dst=(-1, 1, 0))])),
    "target": m.Target(turn=1, sender="GCS", drone="D01", pos=(9, 9, 0)),
    "done_gcs": m.Done(turn=1, sender="GCS", phase=m.Phase.GCS, count=1),
    "done_gcs_final": m.Done(turn=3, sender="GCS", phase=m.Phase.GCS, intent=m.Intent.FINAL),
    "done_gcs_targets": m.Done(turn=2, sender="GCS", phase=m.Phase.GCS, targets=m.AimTable.of([
        m.Aim(drone="D01", pos=(9, 9, 0)), m.Aim(drone="D02", pos=(0, 9, 3))])),
    "ask": m.Ask(turn=1, sender="D01", cells=((1, 0, 0), (0, 1, 0))),
    "ans": m.Ans(turn=1, sender="ENV", kinds=bytes([m.CellKind.EMPTY, m.CellKind.BUILDING])),
    "ask_around": m.Ask(turn=2, sender="H01", cells=((5, 5, 5),), around=((1, 0, 0), (0, 3, 2))),
    "ans_around": m.Ans(turn=2, sender="ENV", kinds=bytes([0, 0, 1, 0, 0, 2, 0, 0, 0, 0, 1, 0, 0]),
                        drones=((0, "D07"), (8, "D02"), (8, "D05"))),
    "nps": m.Nps(turn=1, sender="D01", pos=(1, 0, 0)),
    "nps_unreachable": m.Nps(turn=7, sender="D01", pos=(3, 4, 0), note=m.Note.UNREACHABLE),
    "nps_ranked": m.Nps(turn=3, sender="D01", pos=(2, 0, 0), ranked=rank_steps([(1, 0, 0), (0, 0, 0), (0, 1, 0)])),
    "moves": m.Moves(turn=1, sender="H01", moves=m.StepTable.of([
        m.Step(drone="D01", pos=(1, 0, 0), ranked=rank_steps([(1, 0, 0), (0, 0, 0)])),
        m.Step(drone="D02", pos=(0, 1, 0), note=m.Note.UNREACHABLE)])),
    "moves_deciding": m.Moves(turn=2, sender="H01", moves=m.StepTable.of([])),
    "upd": m.Upd(turn=1, sender="ENV", cells=(m.CellInfo(pos=(0, 0, 0), kind=m.CellKind.EMPTY),
                                              m.CellInfo(pos=(1, 0, 0), kind=m.CellKind.BUILDING, drones=("D01",)))),
    "status": m.Status(turn=1, sender="OBS", drones=m.StatusTable.of([
        m.DroneStatus(drone="D01", pos=(1, 0, 0), state=m.DroneState.DEAD, target=(9, 9, 0), cause=m.Cause.BUILDING),
        m.DroneStatus(drone="D02", pos=(0, 1, 0), state=m.DroneState.ALIVE, note=m.Note.REACHED),
    ]), game="9f2c4e1a7b3d5f60"),
    "over": m.Over(turn=1, sender="SRV", reason=m.EndReason.NO_DRONE_ALIVE, text="D01 crashed into a building",
                   game="9f2c4e1a7b3d5f60"),
    "map_request": m.MapRequest(turn=0, sender="GCS"),
    "map": m.WorldMap(turn=0, sender="ENV", size=(2, 2, 2), buildings=bytes([0b10000000])),
}


def golden() -> dict[str, str]:
    return {name: m.encode(msg).hex() for name, msg in SAMPLES.items()}


def write_or_print(path: pathlib.Path, text: str, description: str | None) -> None:
    """The command line of a generated file: ``--write`` rewrites `path`, else `text` is printed."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--write", action="store_true", help=f"rewrite schema/{path.name}")
    if ap.parse_args().write:
        path.write_text(text)
    else:
        print(text, end="")


if __name__ == "__main__":
    write_or_print(VECTORS_PATH, json.dumps(golden(), indent=1, sort_keys=True) + "\n", __doc__)
