"""A simwire channel served on loopback, for buses in other processes.

``serve_wire(channel, port, clock=..., bitrate=..., sync_period=...)`` hosts the process's own
medium of ``channel`` (the one a plain ``can.Bus(interface="simwire", channel=NAME)`` of this
process opens, so drives simulated here and clients elsewhere share one bus) on 127.0.0.1:PORT.
A client opens ``channel="NAME@127.0.0.1:PORT"`` (protocol: ``axes.sim.wire.protocol``). A client
that disconnects leaves the medium (its queued frames with it); ``WireServer.close()`` closes every
connection and releases the medium. Only loopback addresses are served.
"""

from __future__ import annotations

import contextlib
import ipaddress
import json
import secrets
import socket
import threading
from typing import Any

import can
from can import BusState

from axes.sim.wire import protocol as p
from axes.sim.wire.medium import Medium, Node, WireConfigError
from axes.sim.wire.registry import acquire_medium, release_medium


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


class _Outbox:
    """Frames for one remote node. The delivering thread writes them to the socket itself when the
    socket takes them at once (MSG_DONTWAIT: no thread hop per frame); what it does not take waits
    in a backlog that a thread of the outbox's own writes, so the bus never waits on a slow reader."""

    def __init__(self, name: str) -> None:
        self.cond = threading.Condition(threading.Lock())
        self.backlog = bytearray()
        self.sock: socket.socket | None = None
        self.closed = False
        self.flushing = False  # the outbox thread writes a batch: put() must not overtake it
        self.thread = threading.Thread(target=self._run, name=f"simwire-out-{name}", daemon=True)

    def put(self, msg: can.Message) -> None:
        self.put_bytes(p.pack_frame(msg))

    def put_done(self, count: int) -> None:
        self.put_bytes(p.pack_count(p.DONE, count))

    def put_bytes(self, data: bytes) -> None:
        with self.cond:
            if self.backlog or self.flushing or self.sock is None:
                self.backlog += data
                return
            try:
                sent = self.sock.send(data, socket.MSG_DONTWAIT)
            except BlockingIOError:
                sent = 0
            except OSError:
                return
            if sent < len(data):
                self.backlog += data[sent:]
                self.cond.notify()

    def attach(self, sock: socket.socket) -> None:
        with self.cond:
            self.sock = sock
            self.cond.notify()
        self.thread.start()

    def _run(self) -> None:
        while True:
            with self.cond:
                while not self.backlog and not self.closed:
                    self.cond.wait()
                if self.closed:
                    return
                batch = bytes(self.backlog)
                self.backlog.clear()
                self.flushing = True
            try:
                self.sock.sendall(batch)
            except OSError:
                return
            with self.cond:
                self.flushing = False

    def close(self) -> None:
        with self.cond:
            self.closed = True
            self.cond.notify_all()


class _Client:
    """One remote bus: its node on the medium, its control and receive connections."""

    def __init__(self, server: WireServer, node: Node, outbox: _Outbox, control: socket.socket) -> None:
        self.server = server
        self.node = node
        self.outbox = outbox
        self.control = control
        self.receive: socket.socket | None = None
        self.token = secrets.token_hex(16)
        self._closed = False

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self.server.medium.detach(self.node)
        self.outbox.close()
        for sock in (self.control, self.receive):
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)
                sock.close()
        self.server._forget(self)


class WireServer:
    """The loopback server of one channel's medium (threads: one acceptor, two per client)."""

    def __init__(
        self,
        channel: str,
        port: int = 0,
        *,
        clock: str = "wall",
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
        self.host, self.port = self._listener.getsockname()[:2]
        self._lock = threading.Lock()
        self._clients: list[_Client] = []
        self._pending: dict[str, _Client] = {}
        self._closed = False
        self._acceptor = threading.Thread(target=self._accept, name=f"simwire-server-{channel}", daemon=True)
        self._acceptor.start()

    @property
    def address(self) -> str:
        """The channel string a client in another process opens."""
        return f"{self.channel}@{self.host}:{self.port}"

    def __enter__(self) -> WireServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            clients = list(self._clients)
        with contextlib.suppress(OSError):
            self._listener.shutdown(socket.SHUT_RDWR)  # wakes the blocked accept()
        self._listener.close()
        for client in clients:
            client.close()
        self._acceptor.join(timeout=2.0)
        release_medium(self.channel)

    def _forget(self, client: _Client) -> None:
        with self._lock:
            if client in self._clients:
                self._clients.remove(client)
            self._pending.pop(client.token, None)

    def _accept(self) -> None:
        while True:
            try:
                sock, _ = self._listener.accept()
            except OSError:
                return
            p.configure(sock)
            threading.Thread(target=self._serve, args=(sock,), name="simwire-conn", daemon=True).start()

    def _serve(self, sock: socket.socket) -> None:
        stream = sock.makefile("rb")
        client: _Client | None = None
        kind = None
        try:
            kind, body = p.read_message(stream)
            if kind == p.ATTACH:
                self._attach_receiver(sock, json.loads(body))
                return  # the outbox thread owns the socket now
            if kind != p.HELLO:
                raise p.ProtocolError(f"expected HELLO, got {kind!r}")
            client = self._hello(sock, json.loads(body))
            if client is None:
                return
            self._control_loop(client, stream)
        except (p.ProtocolError, OSError, ValueError):
            pass
        finally:
            if client is not None:
                client.close()
            elif kind != p.ATTACH:
                sock.close()

    def _hello(self, sock: socket.socket, hello: dict[str, Any]) -> _Client | None:
        try:
            if hello.get("channel") != self.channel:
                raise WireConfigError(
                    f"this simwire server serves channel {self.channel!r}, not {hello.get('channel')!r}"
                )
            self.medium.check_agrees(
                bitrate=hello.get("bitrate"), clock=hello.get("clock"), sync_period=hello.get("sync_period")
            )
            outbox = _Outbox(hello.get("name") or "remote")
            node = self.medium.attach(
                outbox.put,
                name=hello.get("name"),
                txqueuelen=hello.get("txqueuelen", 10),
                receive_own=hello.get("receive_own", False),
            )
        except WireConfigError as error:
            sock.sendall(p.pack_fail(0, str(error)))
            sock.close()
            return None
        if self.medium.clock == "wall":
            node.on_done = outbox.put_done
        client = _Client(self, node, outbox, sock)
        with self._lock:
            if self._closed:
                client.close()
                return None
            self._clients.append(client)
            self._pending[client.token] = client
        sock.sendall(p.pack_json(p.WELCOME, {"node": node.name, "token": client.token, **self.medium.params()}))
        return client

    def _attach_receiver(self, sock: socket.socket, body: dict[str, Any]) -> None:
        with self._lock:
            client = self._pending.pop(body.get("token", ""), None)
        if client is None:
            sock.close()
            return
        client.receive = sock
        client.outbox.attach(sock)
        threading.Thread(target=self._watch_receiver, args=(client,), daemon=True).start()

    @staticmethod
    def _watch_receiver(client: _Client) -> None:
        """The receive connection carries nothing from the client: its end is the client's end."""
        with contextlib.suppress(OSError):
            while client.receive.recv(4096):
                pass
        client.close()

    def _control_loop(self, client: _Client, stream: Any) -> None:
        medium, node, sock = self.medium, client.node, client.control
        while True:
            kind, body = p.read_message(stream)
            if kind == p.SEND:
                msg, local_time, timeout = p.unpack_send(body)
                medium.received(node, local_time)
                sock.sendall(self._send(node, msg, timeout))
            elif kind == p.POST:
                msg, _, _ = p.unpack_send(body)
                try:
                    medium.submit(node, msg)
                except can.CanOperationError:
                    client.outbox.put_done(1)  # bus off meanwhile: the frame is lost, its place freed
            elif kind == p.REFUSED:
                with medium.cond:
                    node.enobufs += 1
            elif kind == p.CALL:
                sock.sendall(self._call(node, json.loads(body)))
            else:
                raise p.ProtocolError(f"unexpected message {kind!r}")

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
            else:
                raise ValueError(f"unknown simwire call {what!r}")
        except (KeyError, ValueError) as error:
            return p.pack_fail(0, str(error))
        return p.pack_json(p.REPLY, result)


def serve_wire(
    channel: str,
    port: int = 0,
    *,
    clock: str = "wall",
    bitrate: int = 1_000_000,
    sync_period: float | None = None,
    host: str = "127.0.0.1",
) -> WireServer:
    """Serve ``channel``'s medium on ``host:port`` (loopback; port 0: any free one, see
    ``WireServer.port``) until ``close()``. Buses of this process open it as channel ``channel``,
    buses elsewhere as ``WireServer.address``."""
    return WireServer(channel, port, clock=clock, bitrate=bitrate, sync_period=sync_period, host=host)
