"""A simwire channel served on loopback, for buses in other processes.

``serve_wire(channel, port, clock=..., bitrate=..., sync_period=...)`` hosts the process's own
medium of ``channel`` (the one a plain ``can.Bus(interface="simwire", channel=NAME)`` of this
process opens, so drives simulated here and clients elsewhere share one bus) on 127.0.0.1:PORT.
A client opens ``channel="NAME@127.0.0.1:PORT"`` (protocol: ``axes.sim.wire.protocol``). A client
that disconnects leaves the medium (its queued frames with it); ``WireServer.close()`` closes every
connection and releases the medium. Only loopback addresses are served.

One thread (``simwire-io-NAME``) serves every socket through a selector: it accepts, reads
whatever each client sent (every complete message of a read, submitted to the medium in turn) and
writes what the medium delivered to each client, one write per socket per round. The wall driver
reads the clients' posts itself before it delivers (``WireServer.catch_up``), under the same read lock,
so a frame posted before a delivery is in the medium whichever of this process's threads had the CPU. A frame the
medium delivers from another thread (the wall clock's driver, a drive of this process) is written
by that thread at once (non-blocking), or at the end of its delivery batch
(``Medium.delivery_batch``: a wall driver's step that delivers several frames writes them
together); what the socket does not take at once waits in the client's buffer for the selector
thread. So a frame crosses no thread of the server's on its way, and a burst costs one system
call per socket, not one per frame (figures: ``bench/wire_server.py``, bench/RESULTS.md).
"""

from __future__ import annotations

import contextlib
import ipaddress
import json
import secrets
import select
import selectors
import socket
import threading
from collections.abc import Iterator
from typing import Any

import can
from can import BusState

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.threads import ask_wire_priority
from pvtflow.axes.sim.wire import protocol as p
from pvtflow.axes.sim.wire.medium import Medium, WireConfigError, no_catch_up
from pvtflow.axes.sim.wire.node import Cyclic, Node
from pvtflow.axes.sim.wire.registry import acquire_medium, release_medium


def require_loopback(host: str) -> str:
    """The address to use for ``host``; anything but loopback is refused with a clear error."""
    if host == "localhost":
        return "127.0.0.1"
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        raise WireConfigError(f"simwire serves and connects on loopback only (127.0.0.1), not {host!r}") from None
    if not address.is_loopback or address.version != 4:
        raise WireConfigError(f"simwire serves and connects on loopback only (127.0.0.1), not {host!r}")
    return host


# what the wall driver takes in itself before it delivers (``WireServer.catch_up``): frames (posted, scheduled), and the
# refusals that count against a node; anything else (a call, a blocking send) is left to the selector thread
CAUGHT_UP_KINDS = frozenset({p.POST, p.REFUSED, p.TIMED, p.UNTIME})


class _Outbox:
    """What goes to one socket. The thread that has it writes it at once when the socket takes it
    (non-blocking), or at the end of its delivery batch; the rest waits here for the selector thread."""

    def __init__(self, server: WireServer) -> None:
        self.server = server
        self.lock = threading.Lock()
        self.out = bytearray()
        self.conn: _Conn | None = None  # None until the socket is known (a receive connection attaches)
        self.waiting = False  # the selector thread writes the rest when the socket is writable
        self.closed = False

    def put(self, msg: can.Message) -> None:
        self.put_bytes(p.pack_frame(msg))

    def put_done(self, count: int) -> None:
        self.put_bytes(p.pack_count(p.DONE, count))

    def put_bytes(self, data: bytes) -> None:
        with self.lock:
            if self.closed:
                return
            self.out += data
            if self.conn is None or self.waiting:
                return
            batch = getattr(self.server._local, "batch", None)
            if batch is not None:
                batch.add(self)
                return
            self._write()

    def flush(self) -> None:
        with self.lock:
            if not self.closed and self.conn is not None and not self.waiting and self.out:
                self._write()

    def _write(self) -> None:
        """Under the lock: write what the socket takes; the rest to the selector thread."""
        if self._send():
            return
        self.waiting = True
        self.server._want_write(self)

    def _send(self) -> bool:
        """Under the lock: True when nothing is left to write (or the connection is gone)."""
        try:
            sent = self.conn.sock.send(self.out)
        except BlockingIOError:
            sent = 0
        except OSError:  # the peer went away: its reader sees the end and drops the client
            self.out.clear()
            return True
        del self.out[:sent]
        return not self.out

    def writable(self) -> bool:
        """The selector thread, on a writable socket: write more; True when nothing is left."""
        with self.lock:
            if self.closed or self.conn is None or self._send():
                self.waiting = False
                return True
            return False


class _Conn:
    """One accepted socket: a client's control connection, or its receive connection once attached."""

    def __init__(self, server: WireServer, sock: socket.socket) -> None:
        self.sock = sock
        self.inbuf = bytearray()
        self.outbox = _Outbox(server)
        self.outbox.conn = self
        self.client: _Client | None = None
        self.receiving = False
        self.closed = False


class _Client:
    """One remote bus: its node on the medium, its control and receive connections."""

    def __init__(self, node: Node, frames: _Outbox, control: _Conn) -> None:
        self.node = node
        self.frames = frames
        self.control = control
        self.receive: _Conn | None = None
        self.token = secrets.token_hex(16)
        self.closed = False


class WireServer:
    """The loopback server of one channel's medium: one selector thread for every socket."""

    def __init__(
        self,
        channel: str,
        port: int = 0,
        *,
        clock: Clock | str = Clock.WALL,
        bitrate: int = 1_000_000,
        sync_period: float | None = None,
        host: str = "127.0.0.1",
    ) -> None:
        if "@" in channel or not channel:
            raise WireConfigError(f"a simwire channel name is plain text without '@', got {channel!r}")
        host = require_loopback(host)
        self.channel = channel
        self.medium: Medium = acquire_medium(channel, bitrate=bitrate, clock=clock, sync_period=sync_period)
        try:
            self._listener = socket.create_server((host, port))
        except OSError as error:
            release_medium(channel)
            raise WireConfigError(f"simwire cannot listen on {host}:{port}: {error.strerror}") from None
        self._listener.setblocking(False)
        self.host, self.port = self._listener.getsockname()[:2]
        self._clients: list[_Client] = []
        self._pending: dict[str, _Client] = {}
        self._conns: set[_Conn] = set()
        self._closed = False
        self._local = threading.local()  # .batch: the outboxes a thread's deliveries wrote to, flushed at its end
        self._want_lock = threading.Lock()
        self._want: list[_Outbox] = []
        self._cyclic: dict[int, Cyclic] = {}  # the clients' cyclic sends (a node that leaves takes its own)
        self._woken = False
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._listener, selectors.EVENT_READ, "accept")
        self._selector.register(self._wake_r, selectors.EVENT_READ, "wake")
        if self.medium.delivery_batch is contextlib.nullcontext:
            self.medium.delivery_batch = self._batch
        # one reader of the clients' sockets at a time (the selector thread, or the wall driver in ``catch_up``),
        # so each connection's messages reach the medium in the order they were written
        self._read_lock = threading.Lock()
        self._backlog: list[_Conn] = []  # connections whose buffered messages the selector thread handles next
        self.medium.catch_up = self.catch_up
        self._thread = threading.Thread(target=self._run, name=f"simwire-io-{channel}", daemon=True)
        self._thread.start()

    @property
    def address(self) -> str:
        """The channel string a client in another process opens."""
        return f"{self.channel}@{self.host}:{self.port}"

    def __enter__(self) -> WireServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._wake()
        self._thread.join(timeout=2.0)
        if self.medium.delivery_batch == self._batch:
            self.medium.delivery_batch = contextlib.nullcontext
        if self.medium.catch_up == self.catch_up:
            self.medium.catch_up = no_catch_up
        release_medium(self.channel)

    # -- the selector thread ---------------------------------------------------------------------

    def _run(self) -> None:
        if self.medium.clock is Clock.WALL:  # the wall clock's wire (``axes.canbus.threads``); lockstep waits on none
            ask_wire_priority()
        selector = self._selector
        try:
            while not self._closed:
                events = selector.select()
                with self._batch():
                    for key, mask in events:
                        what = key.data
                        if what == "accept":
                            self._accept()
                        elif what == "wake":
                            self._drain_wake()
                            self._handle_backlog()
                        elif not what.closed:
                            if mask & selectors.EVENT_WRITE and what.outbox.writable():
                                selector.modify(what.sock, selectors.EVENT_READ, what)
                            if mask & selectors.EVENT_READ:
                                with self._read_lock:
                                    self._read(what)
                self._arm_writes()
        finally:
            for client in list(self._clients) + list(self._pending.values()):
                self._close_client(client)
            for conn in list(self._conns):
                self._close_conn(conn)
            selector.close()
            self._listener.close()
            self._wake_r.close()
            self._wake_w.close()

    @contextlib.contextmanager
    def _batch(self) -> Iterator[None]:
        """Deliveries of this thread inside it are written once per socket, at its end."""
        local = self._local
        if getattr(local, "batch", None) is not None:
            yield
            return
        local.batch = batch = set()
        try:
            yield
        finally:
            local.batch = None
            for outbox in batch:
                outbox.flush()

    def _flush_batch(self) -> None:
        """Write what this thread's delivery batch holds so far (a client reading its own bus state
        after a ``set_state`` reply finds the controller error frame already in its socket)."""
        batch = getattr(self._local, "batch", None)
        if batch:
            for outbox in list(batch):
                outbox.flush()
            batch.clear()

    def _want_write(self, outbox: _Outbox) -> None:
        with self._want_lock:
            self._want.append(outbox)
        if threading.current_thread() is not self._thread:
            self._wake()

    def _wake(self) -> None:
        with self._want_lock:
            if self._woken:
                return
            self._woken = True
        with contextlib.suppress(OSError):
            self._wake_w.send(b"w")

    def _drain_wake(self) -> None:
        with self._want_lock:
            self._woken = False
        with contextlib.suppress(OSError):
            while self._wake_r.recv(4096):
                pass

    def _arm_writes(self) -> None:
        with self._want_lock:
            want, self._want = self._want, []
        for outbox in want:
            conn = outbox.conn
            if conn is not None and not conn.closed:
                with contextlib.suppress(KeyError, ValueError, OSError):
                    self._selector.modify(conn.sock, selectors.EVENT_READ | selectors.EVENT_WRITE, conn)

    def _accept(self) -> None:
        while True:
            try:
                sock, _ = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            p.configure(sock)
            sock.setblocking(False)
            conn = _Conn(self, sock)
            self._conns.add(conn)
            self._selector.register(sock, selectors.EVENT_READ, conn)

    def catch_up(self) -> None:
        """What the clients have written to their control connections by now, taken in before the wall
        driver delivers (``Medium.catch_up``; the medium's lock not held): a post waiting in a socket
        while this process's other threads had the CPU would otherwise meet a bus that went on without
        it, a SYNC delivered ahead of a setpoint posted 2 ms before it (measured: bench/RESULTS.md). The
        calling thread reads the sockets itself: waiting for the selector thread to be scheduled was
        itself the delay (the drives' process held 2-4 ms). It takes in posts and refusals only; from
        the first other message on, a connection's messages are the selector thread's (order kept)."""
        if threading.current_thread() is self._thread or self._closed:
            return
        # the lock first: what the selector thread has read but not yet handed to the medium is in too
        with self._read_lock:
            conns = [c for c in list(self._conns) if c.client is not None and not c.receiving and not c.closed]
            if not conns:
                return
            try:
                readable, _, _ = select.select([c.sock for c in conns], [], [], 0)
            except (OSError, ValueError):
                return
            ready = set(readable)
            for conn in conns:
                if conn.sock in ready and not conn.closed:
                    self._read(conn, only=CAUGHT_UP_KINDS)

    def _handle_backlog(self) -> None:
        """The selector thread: the messages ``catch_up`` left in connections' buffers."""
        with self._read_lock:
            backlog, self._backlog = self._backlog, []
            for conn in backlog:
                if not conn.closed:
                    self._consume(conn)

    def _read(self, conn: _Conn, only: frozenset[int] | None = None) -> None:
        """Under the read lock: what ``conn`` sent, handled (``only``: see ``_consume``)."""
        try:
            data = conn.sock.recv(262_144)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            self._drop(conn)
            return
        if conn.receiving:
            return  # the receive connection carries nothing from the client: only its end counts
        conn.inbuf += data
        self._consume(conn, only)

    def _consume(self, conn: _Conn, only: frozenset[int] | None = None) -> None:
        """Under the read lock: the complete messages in ``conn``'s buffer, in order; with ``only``, up
        to the first of another kind, which stays buffered for the selector thread (woken for it)."""
        try:
            messages = p.split_messages(conn.inbuf)
            for at, (kind, body) in enumerate(messages):
                if only is not None and kind not in only:
                    conn.inbuf[:0] = b"".join(p.pack(k, b) for k, b in messages[at:])
                    self._backlog.append(conn)
                    self._wake()
                    return
                self._handle(conn, kind, body)
                if conn.closed or conn.receiving:
                    return
        except (p.ProtocolError, ValueError, OSError):
            self._drop(conn)

    def _handle(self, conn: _Conn, kind: int, body: bytes) -> None:
        client = conn.client
        if client is None:
            if kind == p.HELLO:
                self._hello(conn, json.loads(body))
            elif kind == p.ATTACH:
                self._attach_receiver(conn, json.loads(body))
            else:
                raise p.ProtocolError(f"expected HELLO, got {kind!r}")
            return
        medium, node = self.medium, client.node
        if kind == p.POST:
            msg, sent_at, _ = p.unpack_send(body)
            try:
                # queued when its sender queued it: the loopback's delay is the host's, not the wire's
                medium.submit(node, msg, now=min(sent_at, medium.now()))
            except can.CanOperationError:
                client.frames.put_done(1)  # bus off meanwhile: the frame is lost, its place freed
        elif kind == p.TIMED:
            msgs, due = p.unpack_timed(body)
            with contextlib.suppress(can.CanOperationError):  # bus off: lost, as a posted frame is
                medium.post_at(node, msgs, due)
        elif kind == p.UNTIME:
            medium.cancel_posts(node)
        elif kind == p.SEND:
            msg, local_time, timeout = p.unpack_send(body)
            medium.received(node, local_time)
            conn.outbox.put_bytes(self._send(node, msg, timeout))
        elif kind == p.REFUSED:
            with medium.cond:
                node.enobufs += 1
        elif kind == p.CALL:
            reply = self._call(node, json.loads(body))
            self._flush_batch()  # what the call delivered (a state's error frames) goes before its reply
            conn.outbox.put_bytes(reply)
        else:
            raise p.ProtocolError(f"unexpected message {kind!r}")

    def _hello(self, conn: _Conn, hello: dict[str, Any]) -> None:
        frames = _Outbox(self)
        try:
            if hello.get("channel") != self.channel:
                raise WireConfigError(
                    f"this simwire server serves channel {self.channel!r}, not {hello.get('channel')!r}"
                )
            self.medium.check_agrees(
                bitrate=hello.get("bitrate"), clock=hello.get("clock"), sync_period=hello.get("sync_period")
            )
            node = self.medium.attach(
                frames.put,
                name=hello.get("name"),
                txqueuelen=hello.get("txqueuelen", 10),
                receive_own=hello.get("receive_own", False),
            )
        except WireConfigError as error:
            with contextlib.suppress(OSError):
                conn.sock.send(p.pack_fail(0, str(error)))
            self._close_conn(conn)
            return
        if self.medium.clock is Clock.WALL:
            node.on_done = frames.put_done
        client = _Client(node, frames, conn)
        conn.client = client
        self._clients.append(client)
        self._pending[client.token] = client
        welcome = {"node": node.name, "token": client.token, "epoch": self.medium.epoch, **self.medium.params()}
        conn.outbox.put_bytes(p.pack_json(p.WELCOME, welcome))

    def _attach_receiver(self, conn: _Conn, body: dict[str, Any]) -> None:
        client = self._pending.pop(body.get("token", ""), None)
        if client is None:
            self._close_conn(conn)
            return
        conn.receiving = True
        conn.client = client
        conn.outbox = client.frames
        client.receive = conn
        with client.frames.lock:
            client.frames.conn = conn
        client.frames.flush()  # what the medium delivered before the client attached

    def _drop(self, conn: _Conn) -> None:
        if conn.client is not None:
            self._close_client(conn.client)
        self._close_conn(conn)

    def _close_client(self, client: _Client) -> None:
        if client.closed:
            return
        client.closed = True
        self.medium.detach(client.node)
        with client.frames.lock:
            client.frames.closed = True
        for conn in (client.control, client.receive):
            if conn is not None:
                self._close_conn(conn)
        if client in self._clients:
            self._clients.remove(client)
        self._pending.pop(client.token, None)

    def _close_conn(self, conn: _Conn) -> None:
        if conn.closed:
            return
        conn.closed = True
        with conn.outbox.lock:
            conn.outbox.closed = True
        self._conns.discard(conn)
        with contextlib.suppress(KeyError, ValueError):
            self._selector.unregister(conn.sock)
        with contextlib.suppress(OSError):
            conn.sock.shutdown(socket.SHUT_RDWR)
        conn.sock.close()

    def _send(self, node: Node, msg: can.Message, timeout: float | None) -> bytes:
        try:
            self.medium.submit(node, msg, timeout=timeout)
        except can.CanOperationError as error:
            return p.pack_fail(error.error_code or 0, str(error))
        return p.pack(p.OK)

    def _call(self, node: Node, call: dict[str, Any]) -> bytes:
        try:
            what = call.get("call")
            if what == "stats":
                result: Any = self.medium.stats().to_dict()
            elif what == "state":
                result = node.state.name
            elif what == "set_state":
                self.medium.set_state(call["node"], BusState[call["state"]])
                result = None
            elif what == "inject_error_frame":
                self.medium.inject_error_frame(call["can_id"], bytes.fromhex(call["data"]))
                result = None
            elif what == "add_cyclic":  # the client's broadcast manager: the medium times it (``Medium.add_cyclic``)
                msg = can.Message(
                    arbitration_id=call["can_id"], data=bytes.fromhex(call["data"]), is_extended_id=call["extended"]
                )
                start = call.get("start")
                task = self.medium.add_cyclic(node, msg, float(call["period"]), None if start is None else float(start))
                self._cyclic[id(task)] = task
                result = id(task)
            elif what == "remove_cyclic":
                task = self._cyclic.pop(call["task"], None)
                if task is not None:
                    self.medium.remove_cyclic(task)
                result = None
            else:
                raise ValueError(f"unknown simwire call {what!r}")
        except (KeyError, ValueError, TypeError, WireConfigError) as error:
            return p.pack_fail(0, str(error))
        return p.pack_json(p.REPLY, result)


def serve_wire(
    channel: str,
    port: int = 0,
    *,
    clock: Clock | str = Clock.WALL,
    bitrate: int = 1_000_000,
    sync_period: float | None = None,
    host: str = "127.0.0.1",
) -> WireServer:
    """Serve ``channel``'s medium on ``host:port`` (loopback; port 0: any free one, see
    ``WireServer.port``) until ``close()``. Buses of this process open it as channel ``channel``,
    buses elsewhere as ``WireServer.address``."""
    return WireServer(channel, port, clock=clock, bitrate=bitrate, sync_period=sync_period, host=host)
