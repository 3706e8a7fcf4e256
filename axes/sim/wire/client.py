"""A bus's link to a simwire server in another process (protocol: ``axes.sim.wire.protocol``)."""

from __future__ import annotations

import contextlib
import json
import select
import socket
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import can
from can import BusState

from pvtflow.axes.canbus.can_errors import ControllerState, decode
from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.threads import ask_wire_priority
from pvtflow.axes.sim.wire import protocol as p
from pvtflow.axes.sim.wire.accounting import LateSync, WireStats
from pvtflow.axes.sim.wire.bus_states import BUS_OFF, ERROR_PASSIVE
from pvtflow.axes.sim.wire.medium import WireConfigError
from pvtflow.axes.sim.wire.node import bus_off_error, transmit_queue_full

CONNECT_TIMEOUT = 5.0
WAIT_SLICE_S = 0.001  # a sender waiting for room looks again at least this often
READ_SLICE_S = 0.1  # the reader thread notices a close at least this often
RECV_SIZE = 262_144


class WireLink:
    """Control connection (synchronous requests, the sender's thread reads its own answer) and
    receive connection (a reader thread hands each frame to ``deliver``; on the wall clock a sender
    waiting for room in its FIFO reads it itself meanwhile, so the server's report that a frame left
    reaches the sender without waiting for the reader thread). Whoever reads holds ``_rx_lock``
    only while reading, never while waiting for data."""

    def __init__(
        self,
        name: str,
        host: str,
        port: int,
        hello: dict[str, Any],
        deliver: Callable[[can.Message], None],
        on_close: Callable[[], None],
    ) -> None:
        self.channel = name
        self._deliver = deliver
        self._on_close = on_close
        # one lock per direction of use of the control connection: every write whole (``_lock``), and
        # a request with its reply (``_request_lock``). A frame posted on the wall clock waits for
        # no other thread's reply (the bus watch asks for the node's state on the same connection)
        self._lock = threading.Lock()
        self._request_lock = threading.Lock()
        self.closed = False
        self._interrupted = False  # a request whose reply was never read: the control stream is out of step
        try:
            self._control = p.configure(socket.create_connection((host, port), timeout=CONNECT_TIMEOUT))
        except OSError as error:
            raise can.CanInitializationError(
                f"simwire: no server for channel {name!r} at {host}:{port} ({error.strerror or error})"
            ) from None
        self._control.settimeout(None)
        self._stream = self._control.makefile("rb")
        kind, body = self._request(p.pack_json(p.HELLO, {"channel": name, **hello}))
        if kind == p.FAIL:
            self._control.close()
            raise WireConfigError(p.unpack_fail(body)[1])
        welcome = json.loads(body)
        self.node: str = welcome["node"]
        self.params = {k: welcome[k] for k in ("bitrate", "clock", "sync_period")}
        # the medium's wall-clock bus time base: CLOCK_MONOTONIC is the host's, one for every process
        self.epoch: float = welcome.get("epoch", 0.0)
        self.pipelined = self.params["clock"] == Clock.WALL
        self.txqueuelen: int = hello["txqueuelen"]
        self.state = BusState.ACTIVE  # followed from the controller error frames received
        self._inflight = 0
        self._room = threading.Condition(threading.Lock())
        self._receive = p.configure(socket.create_connection((host, port), timeout=CONNECT_TIMEOUT))
        self._receive.settimeout(None)
        self._receive.sendall(p.pack_json(p.ATTACH, {"token": welcome["token"]}))
        self._receive.setblocking(False)
        self._held = threading.local()  # a thread's posts held for one write (``coalesce``)
        self._rx_lock = threading.Lock()  # one thread at a time reads the receive connection (``read_now``)
        self._rx_buffer = bytearray()
        self._ended = False
        self._closed_told = False  # ``on_close`` called
        self._reader = threading.Thread(target=self._read, name=f"simwire-rx-{self.node}", daemon=True)
        self._reader.start()

    def _request(self, data: bytes) -> tuple[int, bytes]:
        with self._request_lock:
            if self._interrupted:
                raise can.CanOperationError(f"simwire channel {self.channel!r}: a request was interrupted")
            try:
                self._send_now(data)
                return p.read_message(self._stream)
            except can.CanOperationError:  # closed, or gone, before the request went out
                raise
            except (OSError, p.ProtocolError) as error:
                raise can.CanOperationError(f"simwire channel {self.channel!r}: server gone ({error})") from None
            except BaseException:  # Ctrl-C / SIGTERM between request and reply: its reply would answer the next
                self._interrupted = True
                raise

    def send(self, msg: can.Message, local_time: float, timeout: float | None) -> None:
        if self.pipelined:
            self._post(msg, timeout)
            return
        kind, body = self._request(p.pack_send(msg, local_time, timeout))
        if kind == p.FAIL:
            code, text = p.unpack_fail(body)
            raise can.CanOperationError(text, code or None)

    @contextlib.contextmanager
    def coalesce(self) -> Iterator[None]:
        """The wall-clock posts of this thread inside it go to the server in one write, at its end (a
        run of frames sent together: SYNC, time stamp and setpoints). Each frame is still counted in
        flight, refused when the FIFO is full and stamped with its own send time, as without it; one
        socket write instead of one per frame is one kernel call and one GIL release, not several."""
        if getattr(self._held, "posts", None) is not None:
            yield
            return
        self._held.posts = bytearray()
        try:
            yield
        finally:
            self._flush_held()
            self._held.posts = None

    def _flush_held(self) -> None:
        posts = getattr(self._held, "posts", None)
        if posts:
            data = bytes(posts)
            posts.clear()
            self._send_now(data)

    def _post(self, msg: can.Message, timeout: float | None) -> None:
        """Wall clock: count the frame in flight and post it; a full FIFO is refused here."""
        if msg.is_fd or msg.dlc > 8 or len(msg.data) > 8 or msg.is_error_frame:
            raise can.CanOperationError(f"simwire carries classic CAN data and remote frames, got {msg}")
        with self._room:
            if self.state == BUS_OFF:
                raise bus_off_error(self.node)
            full = self._inflight >= self.txqueuelen
        if full:  # reports that frames left may be waiting unread
            self.read_now()
            with self._room:
                full = self._inflight >= self.txqueuelen
        if full and timeout is not None and timeout > 0:
            self._flush_held()  # held frames must reach the wire before a slot can free
            self._wait_for_room(time.monotonic() + timeout)
        with self._room:
            refused = self._inflight >= self.txqueuelen
            if not refused:
                self._inflight += 1
        if refused:
            self._write(p.pack_count(p.REFUSED, 1))
            raise transmit_queue_full(self.node, self.txqueuelen)
        self._write(p.pack_post(msg, self.bus_time()))

    def post_at(self, msgs: list[can.Message], due: float) -> None:
        """Wall clock: ``msgs`` for the medium's transmit schedule at bus time ``due`` (``Medium.post_at``),
        no answer (a round trip would hold the sender as long as the medium's process is held): not counted
        in flight, the FIFO judged by the medium at their due time."""
        for msg in msgs:
            if msg.is_fd or msg.dlc > 8 or len(msg.data) > 8 or msg.is_error_frame:
                raise can.CanOperationError(f"simwire carries classic CAN data and remote frames, got {msg}")
        with self._room:
            if self.state == BUS_OFF:
                raise bus_off_error(self.node)
        self._write(p.pack_timed(msgs, due))

    def cancel_timed(self) -> None:
        """The frames of ``post_at`` not yet due are taken back (``Medium.cancel_posts``), no answer: a quick
        stop that follows never waits for the medium's process."""
        self._write(p.pack(p.UNTIME))

    def _wait_for_room(self, deadline: float) -> None:
        """The waiting sender reads the server's DONE reports itself (a frame's slot is free as soon
        as its report is in, whichever thread reads it)."""
        while True:
            with self._room:
                if self._inflight < self.txqueuelen or self.closed or self._ended or self.state == BUS_OFF:
                    return
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return
            try:
                select.select([self._receive], [], [], min(remaining, WAIT_SLICE_S))
            except (OSError, ValueError):
                return
            self.read_now()

    def _write(self, data: bytes) -> None:
        posts = getattr(self._held, "posts", None)
        if posts is not None:
            posts += data
            return
        self._send_now(data)

    def _send_now(self, data: bytes) -> None:
        with self._lock:
            if self.closed:
                raise can.CanOperationError(f"simwire channel {self.channel!r}: the bus is closed")
            try:
                self._control.sendall(data)
            except OSError as error:
                raise can.CanOperationError(f"simwire channel {self.channel!r}: server gone ({error})") from None

    def _follow_state(self, msg: can.Message) -> None:
        said = decode(msg).state
        if said is None:
            return
        # python-can's states have no error-warning: the controller still sends and acknowledges
        state = {ControllerState.BUS_OFF: BUS_OFF, ControllerState.ERROR_PASSIVE: ERROR_PASSIVE}.get(
            said, BusState.ACTIVE
        )
        with self._room:
            self.state = state
            self._room.notify_all()

    def bus_time(self) -> float:
        """Now, on the medium's wall-clock bus time (CLOCK_MONOTONIC shifted by the server's epoch)."""
        return self.epoch + time.monotonic()

    def call(self, what: str, **args: Any) -> Any:
        kind, body = self._request(p.pack_json(p.CALL, {"call": what, **args}))
        if kind == p.FAIL:
            raise ValueError(p.unpack_fail(body)[1])
        if kind != p.REPLY:
            raise can.CanOperationError(f"simwire channel {self.channel!r}: {what!r} answered by {kind!r}")
        return json.loads(body)

    def _read(self) -> None:
        """The reader thread: waits for data (no lock held) and reads it."""
        if self.pipelined:  # the wall clock's wire (``axes.canbus.threads``); in lockstep no one waits on it
            ask_wire_priority()
        while not self._ended and not self.closed:
            try:
                select.select([self._receive], [], [], READ_SLICE_S)
            except (OSError, ValueError):
                self._ended = True
            self.read_now()
        self._ended = True
        self._tell_closed()

    def read_now(self) -> None:
        """Read what the receive connection holds now, without waiting for more (one thread at a
        time: ``_rx_lock``, held only while reading)."""
        with self._rx_lock:
            try:
                self._pump()
            except (OSError, ValueError, p.ProtocolError):
                self._ended = True

    def _tell_closed(self) -> None:
        with self._room:
            told, self._closed_told = self._closed_told, True
            self._room.notify_all()
        if not told:
            self._on_close()

    def _pump(self) -> None:
        """Under ``_rx_lock``: read what the receive connection holds and hand it on (frames to the
        bus's queue, DONE reports to the in-flight count). The server's end sets ``_ended``."""
        buffer = self._rx_buffer
        while True:
            try:
                chunk = self._receive.recv(RECV_SIZE)
            except (BlockingIOError, InterruptedError):
                break
            if not chunk:
                self._ended = True
                break
            buffer += chunk
            if len(chunk) < RECV_SIZE:
                break  # the socket is drained: no second call to hear so
        done = 0
        channel = self.channel
        for kind, body in p.split_messages(buffer):
            if kind == p.FRAME:
                msg = p.unpack_frame(body, channel)
                if msg.is_error_frame:
                    self._follow_state(msg)
                self._deliver(msg)
            elif kind == p.DONE:
                done += p.unpack_count(body)
        if done:
            with self._room:
                self._inflight -= done
                self._room.notify_all()

    def close(self) -> None:
        with self._lock:
            if self.closed:
                return
            self.closed = True
        with self._room:
            self._room.notify_all()
        for sock in (self._control, self._receive):
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
            sock.close()
        if threading.current_thread() is not self._reader:
            self._reader.join(timeout=2.0)
        self._tell_closed()


class RemoteMedium:
    """The medium's accounting and test hooks, reached through the server (``Medium``'s names)."""

    def __init__(self, link: WireLink) -> None:
        self._link = link

    def stats(self) -> WireStats:
        return WireStats.from_dict(self._link.call("stats"))

    def late_syncs(self) -> list[LateSync]:
        return self.stats().late_syncs

    def set_state(self, name: str, state: BusState) -> None:
        self._link.call("set_state", node=name, state=state.name)

    def inject_error_frame(self, can_id: int = 0x008, data: bytes = bytes(8)) -> None:
        self._link.call("inject_error_frame", can_id=can_id, data=data.hex())

    def node_state(self) -> BusState:
        return BusState[self._link.call("state")]
