"""The MAVLink socket adapter: one pymavlink connection, thread-safe sends, optional signing."""
from __future__ import annotations

import collections
import logging
import os
import socket
import threading
import time
from pathlib import Path

from pymavlink import mavutil

from service.config import MavlinkConfig, SigningConfig, parse_network_url

log = logging.getLogger("service.mavlink")
# pymavlink counts signing time in 10 us units since 2015-01-01
SIGNING_EPOCH_S = 1420070400
# A UDP link's receive buffer: a burst of commands (issue 42's flood: 1,000 a second) waits here while the
# receive thread shares the interpreter with tracking; the default (~208 KiB) overflowed and lost about 1 in 12.
# Linux caps it at net.core.rmem_max.
RECEIVE_BUFFER_BYTES = 4 << 20


def signing_timestamp(unix_s: float) -> int:
    """A MAVLink 2 signing timestamp: 10-us units since 2015-01-01 UTC."""
    return int((unix_s - SIGNING_EPOCH_S) * 1e5)


def read_signing_key(path: str) -> bytes:
    """32-byte secret from a file holding 32 raw bytes or 64 hex characters; ValueError otherwise."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise ValueError(f"mavlink.signing.key_file: cannot read {path}: {exc.strerror}") from exc
    text = data.strip()
    if len(text) == 64:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    if len(data) == 32:
        return data
    raise ValueError(f"mavlink.signing.key_file: {path} must hold 32 raw bytes or 64 hex characters, "
                     f"got {len(data)} bytes")


def check_destination(url: str) -> None:
    """Start-up check of a network link (`udpout:HOST:PORT` etc.): the host resolves, and for udpout the
    OS has a route to it (connecting a UDP socket sends nothing). ConnectionError naming mavlink.url
    otherwise: pymavlink's udpout would start regardless and lose every message without a word.
    Serial devices are checked by opening them."""
    parsed = parse_network_url(url)
    if parsed is None:
        return
    scheme, host, port = parsed
    kind = socket.SOCK_STREAM if scheme.startswith("tcp") else socket.SOCK_DGRAM
    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, socket.AF_INET, kind)[0]
    except (socket.gaierror, IndexError) as exc:
        reason = exc.strerror if isinstance(exc, socket.gaierror) else "no IPv4 address"
        raise ConnectionError(f"mavlink.url: cannot resolve host {host!r} of {url}: {reason}") from exc
    if scheme == "udpout":
        with socket.socket(family, kind, proto) as probe:
            try:
                probe.connect(address)
            except OSError as exc:
                raise ConnectionError(f"mavlink.url: {url} is unreachable: {exc.strerror}") from exc


def keep_stream_on_refusal(mav: object) -> None:
    """Make a refused packet leave its stream's timestamp as it was.

    pymavlink 2.4.50's check_signature records a packet's timestamp for its stream (link id, system,
    component) before it checks the signature, so one forged packet with a far-future timestamp made
    every later packet of the real ground station "old" and refused (measured: tests/
    test_service_mavlink_process.py). The check itself stays pymavlink's; only its bookkeeping is undone.
    """
    check = mav.check_signature  # type: ignore[attr-defined]
    streams = mav.signing.stream_timestamps  # type: ignore[attr-defined]

    def checked(msgbuf: bytearray, system: int, component: int) -> bool:
        key = (msgbuf[-13], system, component)
        previous = streams.get(key)
        if check(msgbuf, system, component):
            return True
        if previous is None:
            streams.pop(key, None)
        else:
            streams[key] = previous
        return False
    mav.check_signature = checked  # type: ignore[attr-defined]


def keep_no_message_history(conn: object) -> None:
    """Make a pymavlink connection keep no history of the messages it received.

    pymavlink's mavfile.post_message stores, per source system, the last message of every type, of every
    instance (NAMED_VALUE_FLOAT, DEBUG_VECT, ... by their name field) and every PARAM_VALUE by name: a peer
    sending made-up names grew the daemon without bound, by about 1 kB a packet (48 MB per 50,000 packets in
    process; bench/fuzz.py's named_message inputs). The service reads none of it; recv_match only needs each
    source system entered (at most 256 small entries).
    """
    states = conn.sysid_state  # type: ignore[attr-defined]

    def post_message(msg: object) -> None:
        system = msg.get_srcSystem()  # type: ignore[attr-defined]
        if system not in states:
            states[system] = mavutil.mavfile_state()
    conn.post_message = post_message  # type: ignore[attr-defined]


class DatagramParser:
    """Parse each UDP datagram on its own: the packets in it, and nothing carried over to the next one.

    pymavlink parses a UDP link as one byte stream: a datagram ending in part of a packet (truncated, or a
    wrong length byte) made the parser take the start of the next datagram as the rest of that packet, so the
    valid command in it was lost as a bad CRC (bench/fuzz.py: the first command after the fuzz went
    unanswered). MAVLink over UDP sends whole packets per datagram, so an unfinished packet is dropped (and
    counted) when the next datagram arrives. Relies on pymavlink 2.4.50's parser fields (buf, buf_index,
    expected_length, have_prefix_error), reset as its own constructor sets them.
    """

    def __init__(self, conn: object) -> None:
        self._conn = conn
        self._pending: collections.deque = collections.deque()
        self.partial_dropped = 0  # datagrams that ended inside a packet
        conn.recv_msg = self.recv_msg  # type: ignore[attr-defined]

    def recv_msg(self) -> object | None:
        """mavfile.recv_msg's contract: the next message (BAD_DATA included) or None when nothing is waiting."""
        conn = self._conn
        conn.pre_message()  # type: ignore[attr-defined]
        if not self._pending:
            data = conn.recv()  # type: ignore[attr-defined]
            if not data:
                return None
            if conn.first_byte:  # type: ignore[attr-defined]
                conn.auto_mavlink_version(data)  # type: ignore[attr-defined]
            mav = conn.mav  # type: ignore[attr-defined]
            mav.buf, mav.buf_index = bytearray(), 0
            mav.expected_length, mav.have_prefix_error = mavutil.mavlink.HEADER_LEN_V1 + 2, False
            self._pending.extend(mav.parse_buffer(data) or ())
            if mav.buf_len() > 0:
                self.partial_dropped += 1
            if not self._pending:
                return None
        msg = self._pending.popleft()
        conn.post_message(msg)  # type: ignore[attr-defined]
        return msg


class SigningCounts:
    """Packets refused by signing: unsigned ones, badly signed ones, and both by message name."""

    def __init__(self) -> None:
        self.refused_unsigned = 0
        self.refused_bad_signature = 0
        self.by_message: dict[str, int] = {}  # at most one key per message of the dialect: bounded
        self._bad_signatures_seen = 0

    def refused(self, msg_id: int, bad_signatures: int) -> None:
        """Count one refusal; bad_signatures is pymavlink's running count, which it raises before asking
        about a badly signed packet (and leaves alone for an unsigned one)."""
        if bad_signatures != self._bad_signatures_seen:
            self._bad_signatures_seen = bad_signatures
            self.refused_bad_signature += 1
        else:
            self.refused_unsigned += 1
        entry = mavutil.mavlink.mavlink_map.get(msg_id)
        name = entry.msgname if entry is not None else str(msg_id)
        self.by_message[name] = self.by_message.get(name, 0) + 1


class MavlinkLink:
    """A pymavlink connection with a send lock; `recv` is called from one receive thread only."""

    def __init__(self, config: MavlinkConfig, source_system: int) -> None:
        self.config = config
        self._lock = threading.Lock()
        self.send_errors = 0
        self.sent = 0
        self._bad_packets = 0  # undecodable, or rejected by signing
        self.signing = SigningCounts()
        self._sending_fails = False  # the last send failed (the first failure of a run is a warning)
        check_destination(config.url)
        try:
            self._conn = mavutil.mavlink_connection(
                config.url, baud=config.baud, source_system=source_system,
                source_component=config.component_id, autoreconnect=True)
        except Exception as exc:  # pymavlink raises OSError / SerialException / ValueError variously
            raise ConnectionError(f"mavlink.url: cannot open {config.url}: {exc}") from exc
        keep_no_message_history(self._conn)
        self._datagrams = DatagramParser(self._conn) if isinstance(self._conn, mavutil.mavudp) else None
        self._enlarge_receive_buffer()
        if config.signing.key_file:
            self._setup_signing(config.signing)

    def _enlarge_receive_buffer(self) -> None:
        """Ask for RECEIVE_BUFFER_BYTES on a UDP link's socket (pymavlink keeps it as `port`); logged at debug
        with what the kernel granted (it reports twice the usable size)."""
        sock = getattr(self._conn, "port", None)
        if not isinstance(sock, socket.socket) or sock.type != socket.SOCK_DGRAM:
            return
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)
            log.debug("event=receive_buffer bytes=%d", sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
        except OSError as exc:
            log.debug('event=receive_buffer error="%s"', exc)

    @property
    def bad_packets(self) -> int:
        """Packets refused: undecodable (bad CRC, unknown id, bad prefix), rejected by signing, or unfinished at
        the end of a UDP datagram."""
        partial = self._datagrams.partial_dropped if self._datagrams is not None else 0
        return self._bad_packets + partial

    @property
    def mav(self) -> object:
        """The pymavlink MAVLink object (message encoders)."""
        return self._conn.mav

    def set_system_id(self, system_id: int) -> None:
        """Send as `system_id` from now on (learned from the autopilot)."""
        with self._lock:
            self._conn.mav.srcSystem = system_id

    @property
    def system_id(self) -> int:
        return self._conn.mav.srcSystem

    def send(self, msg: object) -> bool:
        """Send one message; False (counted, logged at debug) if the OS refused it."""
        with self._lock:
            signing = self._conn.mav.signing
            if signing.sign_outgoing:
                # pymavlink advances the signing timestamp by one (10 us) per message, far slower than time: a
                # receiver meeting this link anew refuses timestamps over a minute behind its own clock
                signing.timestamp = max(signing.timestamp, signing_timestamp(time.time()))
            try:
                self._conn.mav.send(msg)
            except OSError as exc:
                self.send_errors += 1
                # a link that starts failing is worth a warning; each further failure only at debug
                log.log(logging.DEBUG if self._sending_fails else logging.WARNING,
                        'event=send_failed url=%s error="%s" errors=%d', self.config.url, exc, self.send_errors)
                self._sending_fails = True
                return False
            if self._sending_fails:
                log.info("event=send_recovered url=%s errors=%d", self.config.url, self.send_errors)
            self._sending_fails = False
            self.sent += 1
            return True

    def recv(self, timeout_s: float) -> object | None:
        """Next valid message or None after timeout_s (bad / unsigned packets are skipped)."""
        try:
            msg = self._conn.recv_match(blocking=True, timeout=timeout_s)
        except OSError as exc:
            log.warning("event=recv_failed error=%s", exc)
            time.sleep(min(timeout_s, 0.1))  # an OS error repeats at once; do not spin the CPU
            return None
        if msg is None:
            return None
        if msg.get_type() == "BAD_DATA":
            self._bad_packets += 1
            log.debug("event=bad_packet reason=%s", str(getattr(msg, "reason", "")).replace(" ", "_"))
            return None
        return msg

    def close(self) -> None:
        try:
            self._conn.close()
        except OSError:
            pass

    def signing_status(self) -> dict[str, object]:
        """Signing for the status query: on / off, whether unsigned packets pass, packets by verdict
        (accepted signed; refused unsigned; refused with a bad signature: wrong key, replayed or too old a
        timestamp) and the refused ones by message name."""
        signing = self._conn.mav.signing
        return {"enabled": signing.secret_key is not None, "allow_unsigned": self.config.signing.allow_unsigned,
                "accepted_signed": signing.goodsig_count, "refused_unsigned": self.signing.refused_unsigned,
                "refused_bad_signature": self.signing.refused_bad_signature,
                "refused_by_message": dict(self.signing.by_message)}

    def _setup_signing(self, signing: SigningConfig) -> None:
        key = read_signing_key(signing.key_file)
        allow = signing.allow_unsigned
        counts = self.signing

        def allow_unsigned(mav: object, msg_id: int) -> bool:
            """pymavlink asks this for each unsigned or badly signed packet (receive thread only)."""
            if not allow:
                counts.refused(msg_id, mav.signing.badsig_count)  # type: ignore[attr-defined]
            return allow
        # timestamp must only move forward; start at the current time like MAVLink's reference code
        self._conn.setup_signing(key, sign_outgoing=True, allow_unsigned_callback=allow_unsigned,
                                 initial_timestamp=signing_timestamp(time.time()), link_id=signing.link_id)
        keep_stream_on_refusal(self._conn.mav)
        log.info("event=signing_enabled allow_unsigned=%s link_id=%d pid=%d", allow, signing.link_id, os.getpid())
