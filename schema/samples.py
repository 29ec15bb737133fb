"""The canonical sample of every message type, whose bytes are the golden test vectors.

``python -m schema.samples --write`` regenerates schema/vectors.json after a deliberate
change of the contract (bump SCHEMA_VERSION when the bytes of an existing message change).
"""

from __future__ import annotations

import argparse
import json
import pathlib

from .messages import (
    Aim,
    AimTable,
    Ans,
    Ask,
    Cause,
    CellInfo,
    CellKind,
    Connect,
    Done,
    DroneState,
    DroneStatus,
    EndReason,
    Intent,
    MapRequest,
    Message,
    Move,
    Moves,
    MoveTable,
    Note,
    Nps,
    Order,
    OrderTable,
    Over,
    Phase,
    Refused,
    Role,
    Start,
    StartTable,
    Status,
    StatusTable,
    Step,
    StepTable,
    Target,
    Turn,
    Upd,
    Welcome,
    WorldMap,
    WorldSpec,
    encode,
)
from .tables import rank_steps

VECTORS_PATH = pathlib.Path(__file__).with_name("vectors.json")

SAMPLES: dict[str, Message] = {
    "connect_env": Connect(turn=0, sender="ENV", role=Role.ENV),
    "connect_gcs": Connect(turn=0, sender="GCS", role=Role.GCS),
    "connect_drone": Connect(turn=0, sender="D01", role=Role.DRONE, drones=("D01",), autopilot="seed",
                             session="7f3a9c2e41b05d68"),
    "connect_swarm": Connect(turn=0, sender="H01", role=Role.DRONE, drones=("D01", "D02"), autopilot="dstar",
                             cooperative=True),
    "welcome": Welcome(turn=0, sender="SRV", entity="D01", text="You are connected as D01",
                       world=WorldSpec(size=(10, 10, 10), seed=7),
                       starts=StartTable.of([Start(drone="D01", pos=(0, 0, 0))]), game="9f2c4e1a7b3d5f60"),
    "welcome_file_world": Welcome(turn=0, sender="SRV", entity="ENV", text="You are connected as ENV",
                                  world=WorldSpec(size=(2, 2, 2), cells=bytes([0b10000000])),
                                  starts=StartTable.of([Start(drone="D01", pos=(0, 0, 1))])),
    "refused": Refused(turn=0, sender="SRV", text="role GCS is already taken"),
    "turn_gcs": Turn(turn=1, sender="SRV", phase=Phase.GCS),
    "turn_drones": Turn(turn=1, sender="SRV", phase=Phase.DRONES,
                        orders=OrderTable.of([Order(drone="D01", pos=(0, 0, 0), target=(9, 9, 0)),
                                              Order(drone="D02", pos=(0, 1, 0))]), game="9f2c4e1a7b3d5f60"),
    "turn_env": Turn(turn=1, sender="SRV", phase=Phase.ENV,
                     moves=MoveTable.of([Move(drone="D01", src=(0, 0, 0), dst=(1, 0, 0)),
                                         Move(drone="D02", src=(0, 1, 0), dst=(-1, 1, 0))])),
    "target": Target(turn=1, sender="GCS", drone="D01", pos=(9, 9, 0)),
    "done_gcs": Done(turn=1, sender="GCS", phase=Phase.GCS, count=1),
    "done_gcs_final": Done(turn=3, sender="GCS", phase=Phase.GCS, intent=Intent.FINAL),
    "done_gcs_targets": Done(turn=2, sender="GCS", phase=Phase.GCS,
                             targets=AimTable.of([Aim(drone="D01", pos=(9, 9, 0)), Aim(drone="D02", pos=(0, 9, 3))])),
    "ask": Ask(turn=1, sender="D01", cells=((1, 0, 0), (0, 1, 0))),
    "ans": Ans(turn=1, sender="ENV", kinds=bytes([CellKind.EMPTY, CellKind.BUILDING])),
    "ask_around": Ask(turn=2, sender="H01", cells=((5, 5, 5),), around=((1, 0, 0), (0, 3, 2))),
    "ans_around": Ans(turn=2, sender="ENV", kinds=bytes([0, 0, 1, 0, 0, 2, 0, 0, 0, 0, 1, 0, 0]),
                      drones=((0, "D07"), (8, "D02"), (8, "D05"))),
    "nps": Nps(turn=1, sender="D01", pos=(1, 0, 0)),
    "nps_unreachable": Nps(turn=7, sender="D01", pos=(3, 4, 0), note=Note.UNREACHABLE),
    "nps_ranked": Nps(turn=3, sender="D01", pos=(2, 0, 0), ranked=rank_steps([(1, 0, 0), (0, 0, 0), (0, 1, 0)])),
    "moves": Moves(turn=1, sender="H01", moves=StepTable.of([
        Step(drone="D01", pos=(1, 0, 0), ranked=rank_steps([(1, 0, 0), (0, 0, 0)])),
        Step(drone="D02", pos=(0, 1, 0), note=Note.UNREACHABLE)])),
    "upd": Upd(turn=1, sender="ENV", cells=(CellInfo(pos=(0, 0, 0), kind=CellKind.EMPTY),
                                            CellInfo(pos=(1, 0, 0), kind=CellKind.BUILDING, drones=("D01",)))),
    "status": Status(turn=1, sender="OBS", drones=StatusTable.of([
        DroneStatus(drone="D01", pos=(1, 0, 0), state=DroneState.DEAD, target=(9, 9, 0), cause=Cause.BUILDING),
        DroneStatus(drone="D02", pos=(0, 1, 0), state=DroneState.ALIVE, note=Note.REACHED),
    ]), game="9f2c4e1a7b3d5f60"),
    "over": Over(turn=1, sender="SRV", reason=EndReason.NO_DRONE_ALIVE, text="D01 crashed into a building",
                 game="9f2c4e1a7b3d5f60"),
    "map_request": MapRequest(turn=0, sender="GCS"),
    "map": WorldMap(turn=0, sender="ENV", size=(2, 2, 2), buildings=bytes([0b10000000])),
}


def golden() -> dict[str, str]:
    return {name: encode(msg).hex() for name, msg in SAMPLES.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--write", action="store_true", help="rewrite schema/vectors.json")
    args = ap.parse_args()
    text = json.dumps(golden(), indent=1, sort_keys=True) + "\n"
    if args.write:
        VECTORS_PATH.write_text(text)
    else:
        print(text, end="")


if __name__ == "__main__":
    main()
