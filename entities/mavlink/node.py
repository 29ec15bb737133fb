"""``dronesim gcs --mavlink``: the ground station as a fleet of MAVLink vehicles (docs/mavlink.md).

The adapter around `bridge.Bridge`: UDP sockets laid out as PX4's multi-vehicle simulation lays them (the fleet
sends to the ground station, ``--mavlink-gcs udpout:HOST:PORT``, over one shared socket; vehicle n also sends to
an API client on UDP ``--mavlink-api-base`` + n - 1 from a socket of its own, and answers whoever writes to
it there), pymavlink's MAVLink 2 framing, and the game's link (`station_link`). A thread reads the sockets and
decodes each datagram on its own (a datagram of garbage never swallows the next one); its messages go to the
main thread, which owns the bridge. What cannot be taken -- garbage, MAVLink 1 frames, a flood beyond
`MAVLINK_QUEUE` messages waiting -- is refused there, counted and logged (`RejectCounter`)."""

from __future__ import annotations

import argparse
import contextlib
import logging
import selectors
import socket
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from network.signals import Interrupted, Stop, closing, on_stop, waking
from network.transport import Outbox, open_session, zenoh_config
from schema import Keys, MalformedMessage, Over, RejectCounter, RemoteInputError, UsageError
from schema.errors import Refusal
from schema.tuning import MAVLINK_QUEUE, MAVLINK_STOP_S, MAVLINK_TELEMETRY_S

from ..gcs import Ground
from ..station_link import join, listen, play, publisher
from .bridge import Bridge
from .geo import Geo
from .options import parse_udpout
from .vehicle import Mav, Origin

MAVLINK1_MAGIC = 0xFE
_WOKEN = object()  # a signal came: the main thread looks at what it asked
DATAGRAM_MAX = 65535
#: The most datagrams read from one socket before the reader looks at the others and at `Reader.stop`: a
#: flood on one socket neither starves the others nor holds the reader (and the process's exit) up.
READS_A_ROUND = 64
#: The most bytes of frames sent in one datagram (under an Ethernet MTU: no IP fragments).
DATAGRAM_PACK = 1400


@dataclass(frozen=True, slots=True)
class Packet:
    """The messages of one datagram, decoded, and where it came from."""

    origin: Origin
    messages: tuple[Any, ...]


def decode_datagram(data: bytes) -> tuple[Any, ...]:
    """The MAVLink 2 messages of one datagram; a datagram that is not wholly MAVLink 2 frames is refused."""
    parser = mav.MAVLink(None)
    parser.robust_parsing = True
    try:
        messages = parser.parse_buffer(data) or []
    except Exception as exc:  # (pymavlink raises its own errors, and struct's, on odd bytes)
        raise MalformedMessage(f"a datagram of {len(data)} bytes pymavlink cannot read: {exc}",
                               reason="mavlink-garbage") from None
    if not messages or parser.buf_len() or any(m.get_type() == "BAD_DATA" for m in messages):
        raise MalformedMessage(f"a datagram of {len(data)} bytes that is not MAVLink frames: {data[:16].hex()}",
                               reason="mavlink-garbage")
    unknown = [m for m in messages if isinstance(m, mav.MAVLink_unknown)]
    if unknown:  # (an id pymavlink does not know: its checksum cannot be checked, any 0xFD and 12 bytes pass)
        raise MalformedMessage(f"a datagram of {len(data)} bytes with a frame of a message id pymavlink does not "
                               f"know ({unknown[0].get_type()})", reason="mavlink-garbage")
    if any(m.get_msgbuf()[0] == MAVLINK1_MAGIC for m in messages):
        raise RemoteInputError("a MAVLink 1 frame: vehicles speak MAVLink 2", reason="mavlink1")
    return tuple(messages)


class Links:
    """The sockets: port 0 the ground station's (one for the fleet), n vehicle n's, each with an encoder."""

    def __init__(self, gcs: tuple[str, int], api_base: int, systems: Sequence[int]) -> None:
        if not 0 < api_base or api_base + max(systems) - 1 > 65535:
            raise UsageError(f"--mavlink-api-base {api_base}: the ports {api_base}..{api_base + max(systems) - 1} "
                             "must be UDP ports")
        self.gcs = gcs
        self.api = {n: ("127.0.0.1", api_base + n - 1) for n in systems}
        self.sockets: dict[int, socket.socket] = {}
        try:
            for port in (0, *systems):
                sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                sock.bind(("0.0.0.0" if port == 0 else "127.0.0.1", 0))
                sock.setblocking(False)
                self.sockets[port] = sock
        except OSError as exc:
            self.close()
            raise UsageError(f"cannot open the MAVLink sockets: {exc}") from None
        self.encoders = {n: mav.MAVLink(None, srcSystem=n, srcComponent=1) for n in systems}
        self.writers: dict[int, tuple[str, int]] = {}  # the last peer that wrote on a vehicle's port, if not its API
        self.sent = 0  # datagrams
        self._out: dict[tuple[int, tuple[str, int]], list[bytes]] = {}  # frames to send, by (socket, address)

    def encode(self, system: int, msg: Any) -> bytes:
        encoder = self.encoders[system]
        data = msg.pack(encoder)
        encoder.seq = (encoder.seq + 1) % 256
        return data

    def send(self, effect: Mav) -> None:
        """Queue `effect`'s message for its destinations (sent by `flush`)."""
        data = self.encode(effect.system, effect.msg)
        if effect.to is not None:
            self._queue(effect.to.port, effect.to.addr, data)
            return
        self._queue(0, self.gcs, data)
        self._queue(effect.system, self.api[effect.system], data)
        if (writer := self.writers.get(effect.system)) is not None:
            self._queue(effect.system, writer, data)

    def _queue(self, port: int, addr: tuple[str, int], data: bytes) -> None:
        frames = self._out.get((port, addr))
        if frames is None:
            self._out[(port, addr)] = [data]
        else:
            frames.append(data)

    def flush(self) -> None:
        """Send what is queued: a destination's frames, in order, several to a datagram (at most
        `DATAGRAM_PACK` bytes; MAVLink over UDP is a stream of frames, which clients parse as such): a
        turn of a hundred vehicles is a few datagrams to the ground station, one to each API client."""
        out, self._out = self._out, {}
        for (port, addr), frames in out.items():
            sock, size = self.sockets[port], 0
            chunk: list[bytes] = []
            for frame in frames:
                if size + len(frame) > DATAGRAM_PACK and chunk:
                    self._sendto(sock, b"".join(chunk), addr)
                    chunk, size = [], 0
                chunk.append(frame)
                size += len(frame)
            self._sendto(sock, b"".join(chunk), addr)

    def _sendto(self, sock: socket.socket, data: bytes, addr: tuple[str, int]) -> None:
        with contextlib.suppress(OSError):  # (nobody listening there, a full buffer: telemetry is not kept)
            sock.sendto(data, addr)
            self.sent += 1

    def heard(self, origin: Origin) -> None:
        if origin.port and origin.addr != self.api[origin.port]:
            self.writers[origin.port] = origin.addr

    def close(self) -> None:
        for sock in self.sockets.values():
            sock.close()


class Reader:
    """The thread that reads every socket: each datagram decoded on its own and posted (`post`) as a `Packet`,
    at most `limit` messages waiting for the main thread (`taken` frees a packet's); the rest refused and
    counted. Messages, not datagrams: a datagram of 64 KiB holds up to 5,000 frames, some 4 MB decoded. Once a
    datagram finds no room, the next are refused unread (no decode) until the main thread takes a packet: a
    flood costs the reader a read a datagram. It reads at most `READS_A_ROUND` datagrams of a socket in a row
    and looks at `stop` before each: `stop` returns at once whatever the flood."""

    def __init__(self, links: Links, post: Callable[[object], None], rejects: RejectCounter,
                 limit: int = MAVLINK_QUEUE) -> None:
        self.links, self.post, self.rejects, self.limit = links, post, rejects, limit
        self._lock = threading.Lock()
        self._waiting = 0
        self._full = False  # a datagram found no room: refuse unread until the main thread takes a packet
        self._stop = threading.Event()
        self._selector = selectors.DefaultSelector()
        for port, sock in links.sockets.items():
            self._selector.register(sock, selectors.EVENT_READ, port)
        self._thread = threading.Thread(target=self._run, name="mavlink", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()
        self._selector.close()

    def taken(self, packet: Packet) -> None:
        with self._lock:
            self._waiting -= len(packet.messages)
            self._full = False

    def _run(self) -> None:
        while not self._stop.is_set():
            for key, _ in self._selector.select(MAVLINK_STOP_S):  # (the timeout only bounds how long `stop` waits)
                self._read(key.data, key.fileobj)  # type: ignore[arg-type]

    def _read(self, port: int, sock: socket.socket) -> None:
        """Up to `READS_A_ROUND` datagrams of `sock` (until it is empty, or `stop`)."""
        for _ in range(READS_A_ROUND):
            if self._stop.is_set():
                return
            try:
                data, addr = sock.recvfrom(DATAGRAM_MAX)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # (an ICMP error of an earlier send: nothing to read)
                continue
            self._datagram(Origin(port, addr[:2]), data)

    def _datagram(self, origin: Origin, data: bytes) -> None:
        where = f"MAVLink datagram from {origin.addr[0]}:{origin.addr[1]}"
        try:
            with self._lock:
                full = self._full or self._waiting >= self.limit
            if not full:  # (a flood is refused before it costs a decode)
                packet = Packet(origin, decode_datagram(data))
                with self._lock:
                    full = self._waiting + len(packet.messages) > self.limit
                    if full:
                        self._full = True
                    else:
                        self._waiting += len(packet.messages)
            if full:
                raise RemoteInputError(f"more than {self.limit} messages waiting", reason="mavlink-flood")
            self.post(packet)
        except RemoteInputError as err:
            self.rejects.reject(where, err, f"{origin.addr[0]}:{origin.addr[1]}")
        except Exception:  # a bug: logged, the thread goes on
            logging.getLogger("dronesim.GCS").exception("error reading a MAVLink datagram")


class Flushing:
    """The bridge as `station_link.play` drives it, its messages sent (`Links.flush`) each time `play` is
    about to wait: all the frames of what it has just handled travel together."""

    def __init__(self, bridge: Bridge, links: Links) -> None:
        self.bridge, self.links = bridge, links

    def wake(self, now: float) -> float | None:
        self.links.flush()
        return self.bridge.wake(now)

    def admitted(self, welcome: Any) -> Sequence[object]:
        return self.bridge.admitted(welcome)

    def receive(self, msg: Any, now: float) -> Sequence[object]:
        return self.bridge.receive(msg, now)

    def tick(self, now: float) -> Sequence[object]:
        return self.bridge.tick(now)


def run_mavlink(args: argparse.Namespace, logger: logging.Logger) -> Over:
    """Play the game as the MAVLink ground station until it is over."""
    geo = Geo(cell_size=args.cell_size, origin=Geo.parse_origin(args.origin))
    gcs = parse_udpout(args.mavlink_gcs)
    if not (args.turn_period >= 0 and args.turn_period <= 60):
        raise UsageError(f"--turn-period must be 0..60 seconds, got {args.turn_period:g}")
    conf, keys = zenoh_config(args), Keys(args.root)
    with open_session(conf) as session:
        inbox = listen(session, keys, logger)
        with waking(partial(inbox.post, None)):
            member = join(session, inbox, logger, connect_timeout=args.connect_timeout, grace=args.grace)
            ground = Ground.from_welcome(member.welcome, args.targets, args.script)
            bridge = Bridge(ground, geo, period=args.turn_period, telemetry_period=MAVLINK_TELEMETRY_S,
                            now=time.monotonic())
            links = Links(gcs, args.mavlink_api_base, sorted(bridge.vehicles))
            reader = Reader(links, inbox.post, inbox.rejects)
            send = publisher(Outbox(session), keys, logger, lambda text: logger.info("%s", text))

            def perform(effect: object) -> None:
                match effect:
                    case Mav():
                        links.send(effect)
                    case Refusal(what, err):
                        inbox.rejects.reject(what, err)
                    case _:
                        send(effect)  # type: ignore[arg-type]

            signals: list[Interrupted] = []  # (appended by the handler: nothing that takes a lock)

            def other(event: object) -> None:
                while signals:  # the station quits: the game ends at its next phase
                    sig = signals.pop(0)
                    if bridge.quit:
                        raise Stop(sig.signum)  # (a second signal: stop now)
                    bridge.quit = True
                    logger.warning("%s: ending the game at the next GCS phase (again to stop now)", sig.name)
                if event is _WOKEN:
                    return
                if not isinstance(event, Packet):
                    logger.error("unexpected event %r", event)
                    return
                reader.taken(event)
                links.heard(event.origin)
                if logger.isEnabledFor(logging.DEBUG):
                    for msg in event.messages:
                        logger.debug("from %s:%d (port %d): %s", *event.origin.addr, event.origin.port, msg)
                try:
                    effects = bridge.packet(event.origin, event.messages, time.monotonic())
                except Exception:  # a bug: logged, the datagram refused, the game goes on
                    logger.exception("error handling a datagram from %s:%d", *event.origin.addr)
                    inbox.rejects.reject("MAVLink datagram", RemoteInputError("not handled: an error (logged)",
                                                                              reason="mavlink-error"))
                    return
                for effect in effects:
                    perform(effect)
                links.flush()

            if bridge.unseen:
                logger.warning("%d drones past D255 are not MAVLink vehicles (MAVLink's system ids end at 255)",
                               bridge.unseen)
            last = max(bridge.vehicles)
            print(f"MAVLink ground station: systems 1..{last} to udpout:{gcs[0]}:{gcs[1]}, API ports "
                  f"{args.mavlink_api_base}..{args.mavlink_api_base + last - 1}; a turn every {args.turn_period:g} s",
                  flush=True)
            reader.start()
            try:
                with on_stop(signals.append), waking(partial(inbox.post, _WOKEN)):
                    over = play(Flushing(bridge, links), inbox, member, perform, other=other)
                closing(over)  # (a signal from now on: the game's status, not 143)
                links.flush()  # (the last effects, the game over's STATUSTEXTs: `play` returns before it waits)
            finally:
                reader.stop()
                links.close()
        if inbox.rejects.total:
            logger.info("rejected inputs: %s", inbox.rejects.report())
        if bridge.ignored:
            logger.info("MAVLink messages ignored (kinds no vehicle acts on): %s",
                        ", ".join(f"{kind} {n}" for kind, n in bridge.ignored.most_common()))
        member.close()
    print(bridge.station.report(draw=False), flush=True)
    return over
