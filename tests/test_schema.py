"""The wire contract: golden bytes, strict decoding, construction validation, keys."""

from __future__ import annotations

import dataclasses
import json

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from schema import (
    KEY_TABLE,
    MESSAGE_TYPES,
    SCHEMA_VERSION,
    Ans,
    Ask,
    Cause,
    CellInfo,
    CellKind,
    Connect,
    Done,
    DroneState,
    DroneStatus,
    Keys,
    MalformedMessage,
    MapRequest,
    Message,
    Move,
    MoveTable,
    Note,
    Nps,
    Order,
    OrderTable,
    Over,
    Phase,
    Refused,
    RemoteInputError,
    Role,
    Start,
    Status,
    StatusTable,
    StepTable,
    Table,
    Target,
    Turn,
    Upd,
    Welcome,
    WorldMap,
    WorldSpec,
    decode,
    drone_id,
    encode,
    is_drone_id,
    tables,
)
from schema.errors import UsageError
from schema.messages import MAX_COORD, MAX_PAYLOAD, MAX_TURN, drone_list
from schema.samples import SAMPLES, VECTORS_PATH, golden
from schema.tables import Col

VECTORS: dict[str, str] = json.loads(VECTORS_PATH.read_text(encoding="utf-8"))
REPLY_ONLY = {Welcome, Refused, Ans, WorldMap}


def body_of(name: str) -> dict:
    """The MessagePack map of a golden vector, as a mutable dict."""
    return msgpack.unpackb(bytes.fromhex(VECTORS[name]), raw=False)


def pack(obj: object) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


NO_CELL = (-1, -1, -1)


def rows(table: type[Table], *values: tuple) -> bytes:
    """A table's wire bytes, rows given as tuples of raw column values (not checked: for rejections)."""
    return np.array(list(values), table.DTYPE).tobytes()


def rejects(data: bytes, match: str | None = None, **kw) -> MalformedMessage:
    with pytest.raises(MalformedMessage, match=match) as info:
        decode(data, **kw)
    err = info.value
    assert isinstance(err, RemoteInputError)
    assert str(err), "a rejection must say why"
    return err


def mutated(name: str, **changes: object) -> bytes:
    body = body_of(name)
    for k, v in changes.items():
        body[k] = v
    return pack(body)


def without(name: str, *keys: str) -> bytes:
    body = body_of(name)
    for k in keys:
        del body[k]
    return pack(body)


# --------------------------------------------------------------------------- golden vectors


def test_encode_matches_golden(sample: Message, golden: bytes) -> None:
    assert encode(sample).hex() == golden.hex()


def test_decode_golden_gives_sample(sample: Message, golden: bytes) -> None:
    assert decode(golden) == sample
    assert decode(golden, expect=type(sample)) == sample
    assert decode(bytearray(golden)) == sample
    assert decode(memoryview(golden)) == sample


def test_encoding_is_deterministic(sample: Message) -> None:
    again = decode(encode(sample))
    assert again == sample
    assert encode(again) == encode(sample)
    assert encode(dataclasses.replace(sample)) == encode(sample)


def test_wire_header(sample: Message, golden: bytes) -> None:
    body = msgpack.unpackb(golden, raw=False)
    keys = list(body)
    assert keys[:4] == ["v", "t", "turn", "from"], "header first, in a fixed order"
    assert body["v"] == SCHEMA_VERSION
    assert body["t"] == sample.TAG
    assert body["turn"] == sample.turn
    assert body["from"] == sample.sender
    assert "sender" not in body


def test_vectors_file_matches_samples_exactly() -> None:
    assert set(VECTORS) == set(SAMPLES), "schema/vectors.json is stale: regenerate it with samples --write"
    assert golden() == VECTORS


def test_every_message_type_has_a_sample() -> None:
    sampled = {type(m) for m in SAMPLES.values()}
    assert sampled == set(MESSAGE_TYPES)


def test_tags_are_unique_trigram_vocabulary() -> None:
    tags = [cls.TAG for cls in MESSAGE_TYPES]
    assert len(set(tags)) == len(tags)
    assert all(tags)
    for seed_word in ("CONNECT", "DONE", "TGT", "NPS", "UPD", "ASK", "ANS", "OVER"):
        assert seed_word in tags


# --------------------------------------------------------------------------- decode rejects


@pytest.mark.parametrize("data", [
    b"",
    b"\xc1",  # never used in MessagePack
    b"\x85\xa1v",  # truncated map
    bytes.fromhex(VECTORS["target"])[:-1],  # truncated golden
    bytes.fromhex(VECTORS["target"]) + b"\x00",  # trailing garbage
    b"\xff" * 32,
], ids=["empty", "c1", "truncated-map", "truncated-golden", "trailing-bytes", "ff"])
def test_rejects_garbage(data: bytes) -> None:
    rejects(data)


@pytest.mark.parametrize("payload", [[1, 2, 3], 3, "TGT", None, True, b"bytes", 1.5])
def test_rejects_non_map(payload: object) -> None:
    err = rejects(pack(payload))
    assert err.reason == "malformed"


def test_rejects_non_bytes_payload() -> None:
    rejects("not bytes", match="payload must be bytes")  # type: ignore[arg-type]
    rejects(None, match="payload must be bytes")  # type: ignore[arg-type]


@pytest.mark.parametrize("version", [0, SCHEMA_VERSION - 1, SCHEMA_VERSION + 1, -1, str(SCHEMA_VERSION), None,
                                     [SCHEMA_VERSION]])
def test_rejects_wrong_version(version: object) -> None:
    rejects(mutated("target", v=version), match="schema version")


def test_rejects_missing_version() -> None:
    rejects(without("target", "v"), match="schema version")


@pytest.mark.parametrize("version", [True, 1.0])
def test_rejects_version_of_wrong_type(version: object) -> None:
    rejects(mutated("target", v=version), match="schema version")


@pytest.mark.parametrize("tag", ["XYZ", "tgt", "", 1, None, ["TGT"], "MESSAGE"])
def test_rejects_unknown_type_tag(tag: object) -> None:
    rejects(mutated("target", t=tag), match="unknown message type")


def test_rejects_missing_type_tag() -> None:
    rejects(without("target", "t"), match="unknown message type")


def test_rejects_unknown_field() -> None:
    rejects(mutated("target", extra=1), match=r"unknown fields \['extra'\] in TGT")
    rejects(mutated("nps", TAG="NPS"), match="unknown fields")


def test_rejects_sender_spelled_as_attribute_name() -> None:
    body = body_of("target")
    body["sender"] = body.pop("from")
    rejects(pack(body), match="unknown fields")


@pytest.mark.parametrize("name,field", [
    ("target", "turn"), ("target", "from"), ("target", "drone"), ("target", "pos"),
    ("nps", "pos"), ("ask", "cells"), ("turn_gcs", "phase"), ("connect_env", "role"),
    ("welcome", "world"), ("over", "reason"), ("map", "buildings"), ("status", "drones"),
])
def test_rejects_missing_required_field(name: str, field: str) -> None:
    rejects(without(name, field))


def test_optional_fields_may_be_omitted() -> None:
    assert decode(without("nps", "note")) == Nps(turn=1, sender="D01", pos=(1, 0, 0))
    assert decode(without("nps_ranked", "ranked")) == Nps(turn=3, sender="D01", pos=(2, 0, 0))
    assert decode(without("turn_gcs", "orders", "moves")) == SAMPLES["turn_gcs"]
    assert decode(without("connect_env", "drones", "autopilot")) == SAMPLES["connect_env"]


@pytest.mark.parametrize("name,field,value", [
    ("target", "turn", "1"),
    ("target", "turn", True),
    ("target", "turn", 1.0),
    ("target", "turn", -1),
    ("target", "turn", MAX_TURN + 1),
    ("target", "turn", None),
    ("target", "pos", ["9", 9, 0]),
    ("target", "pos", [True, 9, 0]),
    ("target", "pos", [9.0, 9, 0]),
    ("target", "pos", [9, 9]),
    ("target", "pos", [9, 9, 0, 0]),
    ("target", "pos", "9,9,0"),
    ("target", "pos", {"x": 9}),
    ("target", "pos", None),
    ("target", "pos", [9, 9, MAX_COORD + 1]),
    ("target", "drone", 1),
    ("target", "drone", b"D01"),
    ("target", "from", 7),
    ("nps", "note", "MAYBE"),
    ("nps", "note", 0),
    ("turn_gcs", "phase", "OBSERVE"),
    ("turn_gcs", "phase", 1),
    ("connect_env", "role", "SRV"),
    ("connect_env", "autopilot", 3),
    ("connect_env", "autopilot", "x" * 33),
    ("connect_drone", "drones", "D01"),
    ("connect_drone", "drones", [1]),
    ("over", "reason", "BORED"),
    ("over", "text", b"bytes"),
    ("done_gcs", "intent", "MAYBE"),
    ("done_gcs", "count", -1),
    ("done_gcs", "count", True),
    ("done_gcs", "count", "2"),
    ("connect_swarm", "cooperative", 1),
    ("connect_swarm", "cooperative", "yes"),
    ("map", "buildings", "80"),
    ("map", "buildings", b""),
    ("map", "size", [0, 2, 2]),
    ("welcome", "world", [[10, 10, 10], 7]),
    ("welcome", "world", [[10, 10, 10], -1, b""]),
    ("welcome", "world", [[10, 10, 10], 7, b"\x00"]),
    ("welcome", "world", {"size": [10, 10, 10]}),
    ("welcome", "starts", [["D01", [0, 0]]]),
    ("welcome", "text", None),
    ("ask", "cells", []),
    ("ask", "cells", [[1, 0]]),
    ("ans", "cells", [[[1, 0, 0], 3, []]]),
    ("ans", "cells", [[[1, 0, 0], "EMPTY", []]]),
    ("ans", "cells", [[[1, 0, 0], 0, ["X01"]]]),
    ("ans", "cells", [[[1, 0, 0], 0]]),
    ("upd", "cells", "all"),
    ("status", "drones", [["D01", [1, 0, 0], "ALIVE", None, "NONE", "NONE"]]),  # records, not a table
    ("status", "drones", "D01"),
    ("status", "drones", rows(StatusTable, (1, (1, 0, 0), 3, NO_CELL, 0, 0))),  # no 4th DroneState
    ("status", "drones", rows(StatusTable, (1, (1, 0, 0), 0, (-1, 0, 0), 0, 0))),  # a target outside
    ("status", "drones", rows(StatusTable, (1, (1, 0, 0), 0, NO_CELL, 4, 0))),  # no 5th Note
    ("status", "drones", rows(StatusTable, (1, (1, 0, 0), 0, NO_CELL, 0, 6))),  # no 7th Cause
    ("status", "drones", rows(StatusTable, (0, (1, 0, 0), 0, NO_CELL, 0, 0))),  # no drone 0
    ("status", "drones", rows(StatusTable, (1, (1, 0, 0), 0, NO_CELL, 0, 0), (1, (2, 0, 0), 0, NO_CELL, 0, 0))),
    ("status", "drones", rows(StatusTable, (1, (MAX_COORD + 1, 0, 0), 0, NO_CELL, 0, 0))),
    ("status", "drones", rows(StatusTable, (1, (1, 0, 0), 0, NO_CELL, 0, 0))[:-1]),  # not whole rows
    ("turn_drones", "orders", [["D01", [0, 0, 0], None]]),
    ("turn_drones", "orders", rows(OrderTable, (1, (-1, 0, 0), NO_CELL))),
    ("turn_drones", "orders", rows(OrderTable, (1, (0, 0, 0), (-1, -1, 0)))),
    ("turn_env", "moves", rows(MoveTable, (1, (-1, 0, 0), (0, 0, 0)))),
    ("moves", "moves", rows(StepTable, (1, (1, 0, 0), 0, 0), (1, (0, 1, 0), 0, 0))),  # one move per drone
    ("moves", "moves", rows(StepTable, (1, (1, 0, 0), 4, 0))),  # no 5th Note
    ("moves", "moves", rows(StepTable, (1, (1, 0, 0), 0, 0o11))),  # a ranked step twice
    ("moves", "moves", rows(StepTable, (1, (1, 0, 0), 0, 0o101))),  # a hole in the ranking
    ("moves", "moves", rows(StepTable, (1, (1, 0, 0), 0, 8 ** 7))),  # more steps than there are
    ("nps_ranked", "ranked", 0o11),
    ("nps_ranked", "ranked", 0o10),
    ("nps_ranked", "ranked", -1),
    ("nps_ranked", "ranked", 8 ** 7),
    ("nps_ranked", "ranked", True),
    ("nps_ranked", "ranked", 1.0),
])
def test_rejects_wrong_field_value(name: str, field: str, value: object) -> None:
    rejects(mutated(name, **{field: value}))


@pytest.mark.parametrize("kind", [True, 1.0])
def test_rejects_bool_or_float_cell_kind(kind: object) -> None:
    rejects(mutated("upd", cells=[[[1, 0, 0], kind, []]]))


def test_signed_cells_where_allowed() -> None:
    """Sensed cells, cell infos, move destinations and drone statuses may lie outside the world."""
    assert decode(mutated("ask", cells=[[-1, 0, 0]])) == Ask(turn=1, sender="D01", cells=((-1, 0, 0),))
    assert decode(mutated("nps", pos=[-1, 0, 0])).pos == (-1, 0, 0)
    moves = decode(mutated("turn_env", moves=rows(MoveTable, (1, (0, 0, 0), (0, 0, -1))))).moves
    assert moves == (Move(drone="D01", src=(0, 0, 0), dst=(0, 0, -1)),)
    info = decode(mutated("upd", cells=[[[-1, 0, 0], 2, []]])).cells[0]
    assert info == CellInfo(pos=(-1, 0, 0), kind=CellKind.OUTSIDE)
    assert decode(mutated("ask_around", cells=[], around=[[0, 0, 0]])).asked()[1] == (-1, 0, 0)


@pytest.mark.parametrize("drone", ["D1", "d01", "D01x", "D65536", "D123456", "X01", "D", "", "D01\n", "H01", "ENV"])
def test_rejects_invalid_drone_ids(drone: str) -> None:
    rejects(mutated("target", drone=drone), match="drone id")


@pytest.mark.parametrize("sender", ["FOO", "", "D1", "H1", "gcs", "Env"])
def test_rejects_invalid_sender(sender: str) -> None:
    rejects(mutated("target", **{"from": sender}), match="sender")


def test_nps_sender_must_be_a_drone() -> None:
    rejects(mutated("nps", **{"from": "GCS"}), match="sender")
    rejects(mutated("nps", **{"from": "H01"}), match="sender")


def test_rejects_huge_payload() -> None:
    err = rejects(b"\x00" * (MAX_PAYLOAD + 1), match="exceeds")
    assert err.reason == "too-large"


def test_wrong_expected_type() -> None:
    data = bytes.fromhex(VECTORS["target"])
    err = rejects(data, match="TGT message on a key that carries NPS", expect=Nps)
    assert err.reason == "wrong-type"
    err = rejects(data, expect=(Welcome, Refused))
    assert err.reason == "wrong-type"
    assert "WELCOME/REFUSED" in str(err)
    assert decode(data, expect=(Nps, Target)) == SAMPLES["target"]


def test_error_classes() -> None:
    err = MalformedMessage("x")
    assert isinstance(err, RemoteInputError)
    assert err.reason == "malformed"
    assert MalformedMessage("x", reason="too-large").reason == "too-large"


# --------------------------------------------------------------------------- properties


def _only_malformed(data: bytes) -> Message | None:
    try:
        msg = decode(data)
    except MalformedMessage:
        return None
    # whatever decodes is a valid message that round-trips
    assert isinstance(msg, MESSAGE_TYPES)
    assert decode(encode(msg)) == msg
    return msg


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=256))
def test_random_bytes_only_raise_malformed(data: bytes) -> None:
    _only_malformed(data)


_edit = st.tuples(st.sampled_from(["flip", "set", "insert", "delete", "truncate"]),
                  st.integers(min_value=0, max_value=10_000), st.integers(min_value=0, max_value=255))


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(sorted(VECTORS)), st.lists(_edit, min_size=1, max_size=6))
def test_mutated_golden_bytes_only_raise_malformed(name: str, edits: list) -> None:
    data = bytearray.fromhex(VECTORS[name])
    for op, at, byte in edits:
        if not data:
            break
        i = at % len(data)
        if op == "flip":
            data[i] ^= 1 << (byte % 8)
        elif op == "set":
            data[i] = byte
        elif op == "insert":
            data.insert(i, byte)
        elif op == "delete":
            del data[i]
        else:
            del data[i:]
    _only_malformed(bytes(data))


_scalars = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(1 << 63), max_value=(1 << 64) - 1),
    st.floats(allow_nan=True), st.text(max_size=8), st.binary(max_size=8),
    st.sampled_from(["D01", "GCS", "ENV", "H01", "ALIVE", "EMPTY", "DRONES", "TGT", "NONE"]),
)
_values = st.recursive(_scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=4), inner, max_size=3)), max_leaves=12)


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(sorted(VECTORS)), st.data())
def test_structurally_mutated_golden_only_raise_malformed(name: str, data: st.DataObject) -> None:
    """Replace, drop or add fields of a golden message with arbitrary MessagePack values."""
    body = body_of(name)
    for _ in range(data.draw(st.integers(min_value=1, max_value=3))):
        keys = sorted(body) + ["extra"]
        key = data.draw(st.sampled_from(keys))
        if data.draw(st.booleans()) and key in body:
            del body[key]
        else:
            body[key] = data.draw(_values)
    _only_malformed(pack(body))


# --------------------------------------------------------------------------- construction validation


def test_turn_validation() -> None:
    order = Order(drone="D01", pos=(0, 0, 0), target=(1, 1, 1))
    move = Move(drone="D01", src=(0, 0, 0), dst=(1, 0, 0))
    with pytest.raises(MalformedMessage, match="only the DRONES phase carries orders"):
        Turn(turn=1, sender="SRV", phase=Phase.GCS, orders=(order,))
    with pytest.raises(MalformedMessage, match="only the DRONES phase carries orders"):
        Turn(turn=1, sender="SRV", phase=Phase.ENV, orders=(order,))
    with pytest.raises(MalformedMessage, match="only the ENV phase carries moves"):
        Turn(turn=1, sender="SRV", phase=Phase.DRONES, moves=(move,))
    with pytest.raises(MalformedMessage, match="turns start at 1"):
        Turn(turn=0, sender="SRV", phase=Phase.GCS)
    with pytest.raises(MalformedMessage, match="phase"):
        Turn(turn=1, sender="SRV", phase="GCS")  # type: ignore[arg-type]


def test_connect_validation() -> None:
    with pytest.raises(MalformedMessage, match="at least one drone"):
        Connect(turn=0, sender="D01", role=Role.DRONE)
    with pytest.raises(MalformedMessage, match="only a DRONE entity hosts drones"):
        Connect(turn=0, sender="GCS", role=Role.GCS, drones=("D01",))
    with pytest.raises(MalformedMessage, match="distinct"):
        Connect(turn=0, sender="H01", role=Role.DRONE, drones=("D01", "D01"))
    with pytest.raises(MalformedMessage, match="drone id"):
        Connect(turn=0, sender="H01", role=Role.DRONE, drones=("D1",))
    with pytest.raises(MalformedMessage, match="autopilot"):
        Connect(turn=0, sender="D01", role=Role.DRONE, drones=("D01",), autopilot="a" * 33)
    with pytest.raises(MalformedMessage, match="drones must be a tuple"):
        Connect(turn=0, sender="H01", role=Role.DRONE, drones=["D01"])  # type: ignore[arg-type]


def test_header_validation() -> None:
    with pytest.raises(MalformedMessage, match="turn"):
        MapRequest(turn=-1, sender="GCS")
    with pytest.raises(MalformedMessage, match="turn"):
        MapRequest(turn=True, sender="GCS")  # type: ignore[arg-type]
    with pytest.raises(MalformedMessage, match="turn"):
        MapRequest(turn=MAX_TURN + 1, sender="GCS")
    with pytest.raises(MalformedMessage, match="sender"):
        MapRequest(turn=0, sender="XYZ")
    with pytest.raises(MalformedMessage, match="sender"):
        Nps(turn=1, sender="GCS", pos=(0, 0, 0))


def test_cell_validation() -> None:
    with pytest.raises(MalformedMessage, match="target"):
        Target(turn=1, sender="GCS", drone="D01", pos=(-1, 0, 0))
    with pytest.raises(MalformedMessage, match="target"):
        Target(turn=1, sender="GCS", drone="D01", pos=[1, 0, 0])  # type: ignore[arg-type]
    with pytest.raises(MalformedMessage, match="pos"):
        Order(drone="D01", pos=(0, -1, 0))
    with pytest.raises(MalformedMessage, match="src"):
        Move(drone="D01", src=(0, 0, -1), dst=(0, 0, 0))
    with pytest.raises(MalformedMessage, match="pos"):
        Start(drone="D01", pos=(0, 0, -1))
    with pytest.raises(MalformedMessage, match="cell"):
        CellInfo(pos=(0, 0, MAX_COORD + 1), kind=CellKind.EMPTY)
    assert CellInfo(pos=(-MAX_COORD, 0, 0), kind=CellKind.OUTSIDE).pos == (-MAX_COORD, 0, 0)
    with pytest.raises(MalformedMessage, match="cell"):
        CellInfo(pos=(-MAX_COORD - 1, 0, 0), kind=CellKind.OUTSIDE)


def test_ask_cell_count() -> None:
    count = f"1..{Ask.MAX_CELLS}"
    with pytest.raises(MalformedMessage, match=count):
        Ask(turn=1, sender="D01", cells=())
    Ask(turn=1, sender="D01", cells=((0, 0, 0),) * Ask.MAX_CELLS)
    with pytest.raises(MalformedMessage, match=count):
        Ask(turn=1, sender="D01", cells=((0, 0, 0),) * (Ask.MAX_CELLS + 1))
    with pytest.raises(MalformedMessage, match=count):
        Ask(turn=1, sender="H01", cells=((0, 0, 0),), around=((1, 1, 1),) * (Ask.MAX_CELLS // 6 + 1))
    with pytest.raises(MalformedMessage, match="neighbours in range"):
        Ask(turn=1, sender="H01", around=((MAX_COORD, 0, 0),))


def test_ask_around_expands_to_the_six_neighbours_in_order() -> None:
    ask = Ask(turn=1, sender="H01", cells=((9, 9, 9),), around=((1, 1, 1), (5, 0, 0)))
    assert ask.asked() == ((9, 9, 9), (2, 1, 1), (0, 1, 1), (1, 2, 1), (1, 0, 1), (1, 1, 2), (1, 1, 0),
                           (6, 0, 0), (4, 0, 0), (5, 1, 0), (5, -1, 0), (5, 0, 1), (5, 0, -1))


@pytest.mark.parametrize("change,why", [
    (dict(kinds=b"\x00\x03"), "CellKind"),
    (dict(drones=[[2, "D01"]]), "index of an asked cell"),
    (dict(drones=[[1, "D01"], [0, "D02"]]), "increasing order"),
    (dict(drones=[[0, "D02"], [0, "D01"]]), "increasing order"),
    (dict(drones=[[0, "D01"], [0, "D01"]]), "increasing order"),
    (dict(drones=[[0, "X1"]]), "drone id"),
    (dict(drones=[[True, "D01"]]), "pairs"),
    (dict(drones=[0, "D01"]), "pairs"),
])
def test_ans_checks_kinds_and_occupants(change: dict, why: str) -> None:
    rejects(mutated("ans", **change), match=why)


def test_ans_answers_the_asked_cells_in_order() -> None:
    ans = SAMPLES["ans_around"]
    infos = ans.infos(SAMPLES["ask_around"].asked())
    assert infos[0] == CellInfo(pos=(5, 5, 5), kind=CellKind.EMPTY, drones=("D07",))
    assert infos[2] == CellInfo(pos=(0, 0, 0), kind=CellKind.BUILDING)
    assert infos[5] == CellInfo(pos=(1, 0, 1), kind=CellKind.OUTSIDE)
    assert infos[8].drones == ("D02", "D05")
    with pytest.raises(MalformedMessage, match="13 answers for 2 asked cells"):
        ans.infos(((0, 0, 0), (1, 1, 1)))


def test_world_validation() -> None:
    with pytest.raises(MalformedMessage, match="sizes"):
        WorldSpec(size=(0, 1, 1))
    with pytest.raises(MalformedMessage, match="one bit per cell"):
        WorldSpec(size=(2, 2, 2), cells=b"\x00\x00")
    assert WorldSpec(size=(3, 3, 1), cells=b"\x00\x00").cells == b"\x00\x00"  # 9 bits -> 2 bytes
    with pytest.raises(MalformedMessage, match="seed"):
        WorldSpec(size=(2, 2, 2), seed=-1)
    with pytest.raises(MalformedMessage, match="one bit per cell"):
        WorldMap(turn=0, sender="ENV", size=(2, 2, 2), buildings=b"")
    with pytest.raises(MalformedMessage, match="bytes"):
        WorldMap(turn=0, sender="ENV", size=(2, 2, 2), buildings="\x00")  # type: ignore[arg-type]


def test_record_validation() -> None:
    with pytest.raises(MalformedMessage, match="state"):
        DroneStatus(drone="D01", pos=(0, 0, 0), state="ALIVE")  # type: ignore[arg-type]
    with pytest.raises(MalformedMessage, match="CellInfo"):
        Upd(turn=1, sender="ENV", cells=((0, 0, 0),))  # type: ignore[arg-type]
    with pytest.raises(MalformedMessage, match="DroneStatus"):
        Status(turn=1, sender="OBS", drones=("D01",))  # type: ignore[arg-type]
    with pytest.raises(MalformedMessage, match="Start"):
        Welcome(turn=0, sender="SRV", entity="D01", text="", world=WorldSpec(size=(1, 1, 1)), starts=("D01",))
    with pytest.raises(MalformedMessage, match="reason"):
        Over(turn=1, sender="SRV", reason="ALL_REACHED")  # type: ignore[arg-type]
    with pytest.raises(MalformedMessage, match="intent"):
        Done(turn=1, sender="GCS", phase=Phase.GCS, intent="QUIT")  # type: ignore[arg-type]


def test_messages_are_frozen() -> None:
    msg = SAMPLES["target"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        msg.turn = 2  # type: ignore[misc]


def test_drone_status_alive() -> None:
    assert DroneStatus(drone="D01", pos=(0, 0, 0), state=DroneState.ALIVE).alive
    assert not DroneStatus(drone="D01", pos=(0, 0, 0), state=DroneState.DEAD).alive
    assert not DroneStatus(drone="D01", pos=(0, 0, 0), state=DroneState.LOST).alive


def test_drone_ids() -> None:
    assert drone_id(1) == "D01"
    assert drone_id(42) == "D42"
    assert drone_id(100) == "D100"
    assert drone_id(9999) == "D9999" and drone_id(10000) == "D10000" and drone_id(65535) == "D65535"
    for bad in (0, -1, 65536):
        with pytest.raises(ValueError):
            drone_id(bad)
    assert is_drone_id("D01") and is_drone_id("D1234") and is_drone_id("D12345") and is_drone_id("D65535")
    for bad in ("D1", "D65536", "D123456", "D012345", "d01", "H01", 1, None, "D01 ", [], {}, ["D01"], {"D01": 1}):
        assert not is_drone_id(bad)


@pytest.mark.parametrize(("text", "ids"), [
    ("D01", ("D01",)), ("D01,D03", ("D01", "D03")), ("D01-D03", ("D01", "D02", "D03")),
    ("1-3, 7", ("D01", "D02", "D03", "D07")), ("D9 - D10,", ("D09", "D10")), ("65535", ("D65535",)),
])
def test_a_drone_list_gives_the_ids_in_order(text: str, ids: tuple[str, ...]) -> None:
    assert drone_list(text) == ids


@pytest.mark.parametrize("text", ["", " , ", "foo", "D01-Dx", "0", "65536", "D01,D01", "1-3,2", "3-1", "D01;D02",
                                  "1-99999999", "H01", "-1", "D-1"])
def test_anything_else_is_a_usage_error_saying_why(text: str) -> None:
    with pytest.raises(UsageError, match="bad drone list"):
        drone_list(text)


# --------------------------------------------------------------------------- keys


def test_keys_under_default_root() -> None:
    k = Keys()
    assert k.root == "sim"
    assert k.connect == "sim/SRV/CONNECT"
    assert k.turn == "sim/SRV/TURN/*"
    assert k.turn_of(Phase.DRONES) == "sim/SRV/TURN/DRONES"
    assert k.over == "sim/SRV/OVER"
    assert k.status == "sim/OBS/STATUS"
    assert k.gcs_done == "sim/GCS/DONE"
    assert k.ask == "sim/ENV/ASK"
    assert k.map == "sim/ENV/MAP"
    assert k.upd == "sim/ENV/UPD"
    assert k.tgt("D01") == "sim/D01/TGT"
    assert k.nps("D02") == "sim/D02/NPS"
    assert k.any_tgt == "sim/*/TGT"
    assert k.any_nps == "sim/*/NPS"
    assert k.alive("ENV", "a1b2") == "sim/ENV/ALIVE/a1b2"
    assert k.any_alive == "sim/*/ALIVE/*"
    assert k.alive_of("SRV") == "sim/SRV/ALIVE/*"
    assert k.presence_of("sim/H01/ALIVE/a1b2") == ("H01", "a1b2")
    with pytest.raises(ValueError):
        k.presence_of("sim/H01/ALIVE")


@pytest.mark.parametrize("root", ["sim", "game-2", "lab/room_1", "a/b/c"])
def test_keys_under_custom_root(root: str) -> None:
    k = Keys(root)
    assert k.nps("D07") == f"{root}/D07/NPS"
    assert k.connect == f"{root}/SRV/CONNECT"
    assert k.entity_of(k.nps("D07")) == "D07"
    assert k.entity_of(k.tgt("D100")) == "D100"
    assert k.entity_of(k.upd) == "ENV"
    assert k.presence_of(k.alive("H01", "ff00"))[0] == "H01"


@pytest.mark.parametrize("root", ["", "/sim", "sim/", "sim//x", "sim/*", "sim/**", "a b", "sim$", "si?m", "é",
                                  "sim\n"])
def test_bad_roots_rejected(root: str) -> None:
    with pytest.raises(ValueError, match="bad key root"):
        Keys(root)


@pytest.mark.parametrize("key", ["other/D01/NPS", "simx/D01/NPS", "sim", "sim/D01", "sim/D01/NPS/x", "D01/NPS"])
def test_entity_of_rejects_foreign_keys(key: str) -> None:
    with pytest.raises(ValueError):
        Keys("sim").entity_of(key)


def test_key_table_covers_every_message_type() -> None:
    carried = {spec.message for spec in KEY_TABLE if spec.message is not None}
    replies: set[type] = set()
    for spec in KEY_TABLE:
        if isinstance(spec.reply, tuple):
            replies.update(spec.reply)
        elif spec.reply is not None:
            replies.add(spec.reply)
    assert carried | replies == set(MESSAGE_TYPES)
    assert set(MESSAGE_TYPES) - carried == REPLY_ONLY
    assert replies == REPLY_ONLY


def test_key_table_rows_are_consistent() -> None:
    k = Keys("sim")
    built = {k.connect, k.turn_of(Phase.GCS), k.over, k.status, k.gcs_done, k.ask, k.map, k.upd,
             k.tgt("D01"), k.nps("D01"), k.moves("D01"), k.alive("D01", "0a1b")}
    templates = [spec.template for spec in KEY_TABLE]
    assert len(set(templates)) == len(templates)
    for spec in KEY_TABLE:
        key = spec.template.format(drone="D01", entity="D01", session="0a1b", phase="GCS")
        assert f"sim/{key}" in built, spec.template
        assert spec.how in ("put", "query", "liveliness")
        if spec.how == "query":
            assert spec.reply is not None and spec.message is not None
        else:
            assert spec.reply is None
        assert spec.doc
    writers = {spec.message: spec.writer for spec in KEY_TABLE}
    assert writers[Target] == "GCS", "only the ground station may write targets"
    assert writers[Nps] == "DRONE"
    assert writers[Upd] == "ENV"
    assert writers[Turn] == writers[Over] == writers[Status] == "SRV"


def test_a_row_is_checked_by_its_tables_column_rules() -> None:
    """A record of a table's row (DroneStatus, Order, ...) exists only well formed, by the rules its table's
    columns check with numpy: what one refuses, the other refuses."""
    from schema import Cause, Note
    with pytest.raises(MalformedMessage, match="target"):
        DroneStatus(drone="D01", pos=(1, 2, 3), state=DroneState.ALIVE, target=(0, -1, 0))
    with pytest.raises(MalformedMessage, match="note must be a Note"):
        DroneStatus(drone="D01", pos=(1, 2, 3), state=DroneState.ALIVE, note="NONE")  # type: ignore[arg-type]
    rows = StatusTable.empty(1)
    rows["drone"], rows["pos"], rows["target"] = 1, (1, 2, 3), (0, -1, 0)
    with pytest.raises(MalformedMessage, match="target"):
        StatusTable(rows)
    s = DroneStatus(drone="D01", pos=(-1, 2, 3), state=DroneState.DEAD, target=(4, 5, 6), cause=Cause.OUTSIDE)
    assert Status(turn=1, sender="OBS", drones=(s,)).drones[0] == s and s.note is Note.NONE
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.pos = (0, 0, 0)  # type: ignore[misc]


# --------------------------------------------------------------------------- tables


def test_tables_hold_the_records_they_were_given_and_travel_as_their_rows() -> None:
    states = (DroneStatus(drone="D1000", pos=(-1, 0, 3), state=DroneState.DEAD, cause=Cause.OUTSIDE),
              DroneStatus(drone="D07", pos=(1, 2, 3), state=DroneState.ALIVE, target=(4, 5, 6), note=Note.REACHED))
    msg = Status(turn=3, sender="OBS", drones=states)
    assert type(msg.drones) is StatusTable and len(msg.drones) == 2
    assert msg.drones == states and tuple(msg.drones) == states and msg.drones[1] == states[1]
    assert msg.drones[-1] == states[-1] and msg.drones[:1] == states[:1] and msg.drones[5:] == ()
    assert msg.drones.ids() == ["D1000", "D07"] and msg.drones.numbers.tolist() == [1000, 7]
    assert msg.drones.column("target").tolist() == [[-1, -1, -1], [4, 5, 6]]
    again = decode(encode(msg))
    assert again == msg and hash(again) == hash(msg)
    assert msgpack.unpackb(encode(msg))["drones"] == msg.drones.rows.tobytes()
    assert StatusTable.DTYPE.itemsize == 2 + 12 + 1 + 12 + 1 + 1


def test_a_welcome_gives_each_drone_its_start_cell() -> None:
    from schema import Start, StartTable, Welcome, WorldSpec

    starts = (Start(drone="D03", pos=(1, 2, 3)), Start(drone="D10", pos=(0, 0, 9)))
    welcome = decode(encode(Welcome(turn=0, sender="SRV", entity="H01", text="hi", world=WorldSpec(size=(9, 9, 9)),
                                    starts=starts)))
    assert type(welcome.starts) is StartTable and tuple(welcome.starts) == starts
    assert welcome.starts.cells() == {"D03": (1, 2, 3), "D10": (0, 0, 9)}


def test_a_table_is_immutable() -> None:
    table = SAMPLES["status"].drones
    with pytest.raises(AttributeError):
        table.rows = None  # type: ignore[misc]
    with pytest.raises(ValueError):
        table.rows["pos"][0] = (5, 5, 5)


@pytest.mark.parametrize("drone", ["D00", "D001", "D0100", "D01000"])
def test_drone_ids_are_canonical(drone: str) -> None:
    """One drone, one id: a table's drone column holds numbers, so D001 cannot be another drone than D01."""
    assert not is_drone_id(drone)
    rejects(mutated("target", drone=drone), match="drone id")
    with pytest.raises(MalformedMessage, match="drone id"):
        DroneStatus(drone=drone, pos=(1, 0, 0), state=DroneState.ALIVE)


@settings(max_examples=300, deadline=None)
@given(st.sampled_from([Col.CELL, Col.SIGNED, Col.OPTIONAL]),
       st.lists(st.one_of(st.just((-1, -1, -1)), st.tuples(*[st.sampled_from(
           [0, 1, 7, MAX_COORD, MAX_COORD + 1, -1, -2, -MAX_COORD, -MAX_COORD - 1, 2**31 - 1, -2**31])] * 3)),
           min_size=1, max_size=12))
def test_a_cell_column_is_judged_as_its_rows_are(kind: Col, cells: list) -> None:
    """A table's cell column (checked with numpy) and each row's cell (checked in Python): the same rule."""
    col = np.array(cells, np.int32).reshape(-1, 3)
    one_by_one = all(c == (-1, -1, -1) and kind is Col.OPTIONAL or tables._cell_ok(c, tables._LOWEST[kind])
                     for c in map(tuple, col.tolist()))
    assert tables._column_ok(col, kind) == one_by_one


_BOUNDS = [0, 1, 7, MAX_COORD, MAX_COORD + 1, -1, -2, -MAX_COORD, -MAX_COORD - 1, 2**31 - 1, -2**31]


@st.composite
def _raw_rows(draw: st.DrawFn) -> tuple[type, np.ndarray]:
    """Rows of a random table class, each column's values drawn around its rule's bounds (many invalid)."""
    from schema.messages import TABLES
    cls = draw(st.sampled_from(TABLES))
    n = draw(st.integers(1, 2 * tables.CHECK_FEW_ROWS + 2))
    rows = cls.empty(n)
    for name, kind in cls.LAYOUT:
        if kind is Col.DRONE:
            values: object = draw(st.lists(st.sampled_from([0, 1, 2, 3, 40, 65535]), min_size=n, max_size=n))
        elif kind is Col.RANKED:
            values = draw(st.lists(st.sampled_from([0, 1, 7, 8, 0o21, 0o12, 0o1234567, 0o7654321, 0o11,
                                                    tables.RANKED_LIMIT, 2**32 - 1]), min_size=n, max_size=n))
        elif isinstance(kind, Col):
            cell = st.one_of(st.just((-1, -1, -1)), st.tuples(*[st.sampled_from(_BOUNDS)] * 3))
            values = draw(st.lists(cell, min_size=n, max_size=n))
        else:
            values = draw(st.lists(st.sampled_from([0, 1, len(kind) - 1, len(kind), 255]), min_size=n, max_size=n))
        if draw(st.booleans()):  # mostly valid columns, so that a later column's rule is reached too
            values = rows[name].copy() if kind is not Col.DRONE else np.arange(1, n + 1)
        rows[name] = values
    return cls, rows


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_raw_rows())
def test_a_table_is_judged_row_by_row_as_by_columns(drawn: tuple[type, np.ndarray]) -> None:
    """A few rows are checked one by one in Python, more by columns with numpy: the same verdict, the same
    reason (the first column that fails), whatever the rows."""
    cls, rows = drawn
    assert cls._why_few(rows) == cls._why_columns(rows)
