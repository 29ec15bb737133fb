"""The wire contract: key expressions, message types, codec, errors. See schema/README.md."""

from .errors import (
    DronesimError, MalformedMessage, OutOfRange, RejectCounter, RemoteInputError, StaleTurn,
    UnknownEntity, UsageError, WrongSender,
)
from .keys import KEY_TABLE, Keys, KeySpec
from .messages import (
    MESSAGE_TYPES, SCHEMA_VERSION, Aim, Ans, Ask, Cause, Cell, CellInfo, CellKind, Connect, Done,
    DroneState, DroneStatus, EndReason, MapRequest, Message, Move, Moves, Note, Nps, Order, Over, Phase,
    Intent, Refused, Role, WorldSpec, Start, Status, StatusRequest, Step, Target, Turn, Upd, Welcome, WorldMap, decode, drone_id,
    encode, is_drone_id, AimTable, MoveTable, OrderTable, StartTable, StatusTable, StepTable, TABLES,
)
from .tables import Col, Table

__all__ = [
    "DronesimError", "MalformedMessage", "OutOfRange", "RejectCounter", "RemoteInputError", "StaleTurn",
    "UnknownEntity", "UsageError", "WrongSender", "KEY_TABLE", "Keys", "KeySpec", "MESSAGE_TYPES",
    "SCHEMA_VERSION", "Ans", "Ask", "Cause", "Cell", "CellInfo", "CellKind", "Connect", "Done",
    "DroneState", "DroneStatus", "EndReason", "MapRequest", "Message", "Move", "Moves", "Note", "Nps", "Order",
    "Over", "Phase", "Intent", "WorldSpec", "Refused", "Role", "Aim", "Step", "Start", "Status", "StatusRequest", "Target", "Turn", "Upd", "Welcome", "WorldMap",
    "decode", "drone_id", "encode", "is_drone_id", "AimTable", "MoveTable", "OrderTable", "StartTable", "StatusTable", "StepTable", "TABLES",
    "Col", "Table",
]
