"""The simwire loopback protocol: length-prefixed messages over TCP (TCP_NODELAY).

Every message is a 4-byte little-endian length, then a kind byte and its body. A client opens two
connections to the server:

* the **control** connection carries requests, each answered before the next is sent: ``HELLO``
  (JSON: channel, bitrate, clock, sync_period, txqueuelen, receive_own, name) -> ``WELCOME`` (JSON:
  node, token, the medium's parameters) or ``FAIL``; ``SEND`` (a frame, the sender's lockstep local
  time and its send timeout) -> ``OK`` or ``FAIL`` (errno + text: ENOBUFS, bus off); ``CALL``
  (JSON: a medium hook: stats, set_state, inject_error_frame, state; on the wall clock add_cyclic /
  remove_cyclic, a cyclic send the medium times) -> ``REPLY`` (JSON) or ``FAIL``.
  On the lockstep clock a send is acknowledged synchronously (the FIFO bound is judged in
  virtual time, which only the medium knows), so a full transmit FIFO is the sender's error at
  its ``send()``, as on SocketCAN, and the sending thread reads its own answer (no thread hop).
  On the wall clock a round trip per frame would cost the master more than the frame costs the
  wire, so sends are pipelined: ``POST`` (a frame, no answer); the client counts its frames in
  flight (posted, not yet reported ``DONE``) and raises ENOBUFS itself when ``txqueuelen`` are,
  telling the server (``REFUSED``, no answer) so the medium's ENOBUFS count stays whole. Frames in
  the socket count as queued: the client's FIFO is never emptier than the medium's. Each ``POST``
  carries the bus time its sender queued it (the medium's ``epoch`` from ``WELCOME`` +
  CLOCK_MONOTONIC, the host's clock) and the medium queues it at that time: the loopback's delay
  is the host's, not the wire's. ``TIMED`` (a due bus time and frames, no answer) hands frames to the
  medium's transmit schedule (``Medium.post_at``): they enter the node's FIFO at that time, not
  counted in flight (the interface's until then), and no ``DONE`` is reported for them; ``UNTIME`` (no
  body, no answer) takes back those not yet due (``Medium.cancel_posts``).
* the **receive** connection: ``ATTACH`` (JSON: the token) and then the server streams ``FRAME``s
  (time stamp, identifier, flags, DLC, 8 data bytes), in bus order, batched when they come fast,
  and on the wall clock ``DONE`` (count) when frames of this client left its FIFO (sent, or
  dropped at bus off). The client follows its bus state from the controller error frames it
  receives (CAN_ERR_BUSOFF, CAN_ERR_CRTL, CAN_ERR_RESTARTED), as a socketcan user does.
"""

from __future__ import annotations

import json
import socket
import struct
from typing import Any

import can

HELLO, WELCOME, SEND, OK, FAIL, CALL, REPLY, ATTACH, FRAME, POST, DONE, REFUSED, TIMED, UNTIME = b"HWSKFCRAMPDNTU"
_LEN = struct.Struct("<I")
_FRAME = struct.Struct("<dIBB8s")  # time stamp, identifier, flags, dlc, data
_SEND = struct.Struct("<ddIBB8s")  # local time, timeout (< 0: None), identifier, flags, dlc, data
_FAIL = struct.Struct("<i")
_COUNT = struct.Struct("<I")
_TIMED = struct.Struct("<dI")  # due bus time, frames
_TIMED_FRAME = struct.Struct("<IBB8s")  # identifier, flags, dlc, data
EXTENDED, REMOTE, ERROR, RX = 1, 2, 4, 8
MAX_MESSAGE = 16 * 1024 * 1024


class ProtocolError(ConnectionError):
    """The peer sent something this protocol does not have, or went away."""


def pack(kind: int, body: bytes = b"") -> bytes:
    return _LEN.pack(len(body) + 1) + bytes((kind,)) + body


def pack_json(kind: int, value: Any) -> bytes:
    return pack(kind, json.dumps(value).encode())


def _flags(msg: can.Message) -> int:
    return (
        (EXTENDED if msg.is_extended_id else 0)
        | (REMOTE if msg.is_remote_frame else 0)
        | (ERROR if msg.is_error_frame else 0)
        | (RX if msg.is_rx else 0)
    )


def pack_frame(msg: can.Message) -> bytes:
    body = _FRAME.pack(msg.timestamp, msg.arbitration_id, _flags(msg), msg.dlc, bytes(msg.data))
    return _LEN.pack(len(body) + 1) + bytes((FRAME,)) + body


def unpack_frame(body: bytes, channel: str) -> can.Message:
    timestamp, can_id, flags, dlc, data = _FRAME.unpack(body)
    return can.Message(
        timestamp=timestamp,
        arbitration_id=can_id,
        is_extended_id=bool(flags & EXTENDED),
        is_remote_frame=bool(flags & REMOTE),
        is_error_frame=bool(flags & ERROR),
        is_rx=bool(flags & RX),
        dlc=dlc,
        data=b"" if flags & REMOTE else data[: min(dlc, 8)],
        channel=channel,
        check=False,
    )


def pack_send(msg: can.Message, local_time: float, timeout: float | None) -> bytes:
    body = _SEND.pack(
        local_time, -1.0 if timeout is None else timeout, msg.arbitration_id, _flags(msg), msg.dlc, bytes(msg.data)
    )
    return pack(SEND, body)


def unpack_send(body: bytes) -> tuple[can.Message, float, float | None]:
    local_time, timeout, can_id, flags, dlc, data = _SEND.unpack(body)
    msg = can.Message(
        arbitration_id=can_id,
        is_extended_id=bool(flags & EXTENDED),
        is_remote_frame=bool(flags & REMOTE),
        is_error_frame=bool(flags & ERROR),
        dlc=dlc,
        data=b"" if flags & REMOTE else data[: min(dlc, 8)],
        check=False,
    )
    return msg, local_time, None if timeout < 0 else timeout


def pack_post(msg: can.Message, sent_at: float) -> bytes:
    """``sent_at``: the wall-clock bus time the sender queued it (the loopback's delay is not the wire's)."""
    return pack(POST, _SEND.pack(sent_at, -1.0, msg.arbitration_id, _flags(msg), msg.dlc, bytes(msg.data)))


def pack_timed(msgs: list[can.Message], due: float) -> bytes:
    """Frames for the medium's transmit schedule at bus time ``due`` (``Medium.post_at``)."""
    body = _TIMED.pack(due, len(msgs)) + b"".join(
        _TIMED_FRAME.pack(m.arbitration_id, _flags(m), m.dlc, bytes(m.data)) for m in msgs
    )
    return pack(TIMED, body)


def unpack_timed(body: bytes) -> tuple[list[can.Message], float]:
    due, count = _TIMED.unpack_from(body)
    msgs = []
    for i in range(count):
        can_id, flags, dlc, data = _TIMED_FRAME.unpack_from(body, _TIMED.size + i * _TIMED_FRAME.size)
        msgs.append(
            can.Message(
                arbitration_id=can_id,
                is_extended_id=bool(flags & EXTENDED),
                is_remote_frame=bool(flags & REMOTE),
                dlc=dlc,
                data=b"" if flags & REMOTE else data[: min(dlc, 8)],
                check=False,
            )
        )
    return msgs, due


def pack_count(kind: int, count: int) -> bytes:
    return pack(kind, _COUNT.pack(count))


def unpack_count(body: bytes) -> int:
    return _COUNT.unpack(body)[0]


def pack_fail(code: int, text: str) -> bytes:
    return pack(FAIL, _FAIL.pack(code) + text.encode())


def unpack_fail(body: bytes) -> tuple[int, str]:
    (code,) = _FAIL.unpack_from(body)
    return code, body[_FAIL.size :].decode()


def read_message(stream: Any) -> tuple[int, bytes]:
    """One message from a buffered binary stream (``socket.makefile('rb')``)."""
    head = stream.read(4)
    if len(head) < 4:
        raise ProtocolError("connection closed")
    (length,) = _LEN.unpack(head)
    if not 1 <= length <= MAX_MESSAGE:
        raise ProtocolError(f"bad message length {length}")
    body = stream.read(length)
    if len(body) < length:
        raise ProtocolError("connection closed")
    return body[0], body[1:]


def split_messages(buffer: bytearray) -> list[tuple[int, bytes]]:
    """Complete messages at the front of ``buffer`` (removed from it)."""
    out: list[tuple[int, bytes]] = []
    pos = 0
    size = len(buffer)
    while size - pos >= 4:
        (length,) = _LEN.unpack_from(buffer, pos)
        if not 1 <= length <= MAX_MESSAGE:
            raise ProtocolError(f"bad message length {length}")
        if size - pos - 4 < length:
            break
        out.append((buffer[pos + 4], bytes(buffer[pos + 5 : pos + 4 + length])))
        pos += 4 + length
    del buffer[:pos]
    return out


def configure(sock: socket.socket) -> socket.socket:
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock
