"""``SimWireBus``: the python-can interface ``simwire`` (entry point ``can.interface``).

    can.Bus(interface="simwire", channel="cell", bitrate=1_000_000, clock="lockstep", sync_period=0.001)
    can.Bus(interface="simwire", channel="cell@127.0.0.1:29536")   # the medium served by another process

A plain channel name is this process's medium of that name (``axes.sim.wire.registry``); a
``NAME@127.0.0.1:PORT`` channel is the medium a ``serve_wire`` of another process hosts. Each bus
is one node of the medium (package docstring for the semantics).
"""

from __future__ import annotations

import contextlib
import queue
import re
import time
from collections import deque
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from typing import Any

import can
from can import BusState
from can.typechecking import AutoDetectedConfig, CanFilters

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.sim.wire.client import RemoteMedium, WireLink
from pvtflow.axes.sim.wire.medium import Medium, WireConfigError
from pvtflow.axes.sim.wire.node import DEFAULT_TXQUEUELEN, Cyclic, Node
from pvtflow.axes.sim.wire.registry import acquire_medium, open_channels, release_medium
from pvtflow.axes.sim.wire.server import require_loopback

_REMOTE = re.compile(r"^(?P<name>[^@]+)@(?P<host>[^:@]+):(?P<port>\d{1,5})$")
_CLOSED = object()
END_MARGIN_S = 1e-6  # a frame not yet handled: its node has heard the wire up to just before its end


def parse_channel(channel: str) -> tuple[str, str | None, int | None]:
    """``NAME`` -> (NAME, None, None); ``NAME@HOST:PORT`` -> (NAME, HOST, PORT), HOST loopback only."""
    if not isinstance(channel, str) or not channel:
        raise WireConfigError(f"a simwire channel is NAME or NAME@127.0.0.1:PORT, got {channel!r}")
    if "@" not in channel:
        return channel, None, None
    match = _REMOTE.match(channel)
    if match is None or not 0 < int(match["port"]) < 65536:
        raise WireConfigError(f"a simwire channel is NAME or NAME@127.0.0.1:PORT, got {channel!r}")
    return match["name"], require_loopback(match["host"]), int(match["port"])


class SimWireBus(can.BusABC):
    """One node on a simulated classic CAN bus with bit timing, arbitration and a bounded
    transmit FIFO.

    :param channel: ``NAME`` (this process) or ``NAME@127.0.0.1:PORT`` (a ``serve_wire`` elsewhere)
    :param bitrate: bit/s; the medium's creator sets it (default 1 Mbit/s), later openers must agree
        or leave it None
    :param clock: ``"wall"`` or ``"lockstep"`` (same rule; default wall)
    :param sync_period: seconds; required by lockstep (same rule)
    :param txqueuelen: this node's transmit FIFO bound (default 10, SocketCAN's)
    :param receive_own_messages: the node receives its own frames (is_rx False), as on socketcan
    :param node_name: the node's name in the medium's accounting and test hooks (default nodeN)
    :param cyclic_by_medium: a served channel: ``send_periodic`` of one frame is timed by the medium in the
        server's process, as SocketCAN's broadcast manager times it in the kernel (default False: python-can's
        thread here; a master that follows a SYNC timed there needs its echo well within a period,
        docs/wall-clock.md). In-process media always time it themselves.
    """

    def __init__(
        self,
        channel: str = "simwire",
        can_filters: CanFilters | None = None,
        *,
        bitrate: int | None = None,
        clock: str | None = None,
        sync_period: float | None = None,
        txqueuelen: int = DEFAULT_TXQUEUELEN,
        receive_own_messages: bool = False,
        node_name: str | None = None,
        cyclic_by_medium: bool = False,
        fd: bool = False,
        **kwargs: Any,
    ) -> None:
        if fd:
            raise WireConfigError("simwire is a classic CAN bus: CAN FD is not simulated")
        name, host, port = parse_channel(channel)
        self.channel_info = f"simwire channel {channel}"
        self.channel = channel
        self._rx: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._waiting: deque[float] = deque()  # in-process: the ends of the frames in ``_rx`` (``taken_until``)
        self._in_hand: float | None = None  # the end of the frame its reader took last, until it comes back
        self._local_time = 0.0
        self._medium: Medium | None = None
        self._node: Node | None = None
        self._link: WireLink | None = None
        self._closed = False
        self._cyclic_by_medium = bool(cyclic_by_medium)
        if host is None:
            self._medium = acquire_medium(name, bitrate=bitrate, clock=clock, sync_period=sync_period)
            try:
                self._node = self._medium.attach(
                    self._arrive, name=node_name, txqueuelen=txqueuelen, receive_own=receive_own_messages
                )
            except WireConfigError:
                release_medium(name)
                raise
            self._name = name
            self.clock = self._medium.clock
            self.node_name = self._node.name
        else:
            hello = {
                "bitrate": bitrate,
                "clock": clock,
                "sync_period": sync_period,
                "txqueuelen": txqueuelen,
                "receive_own": receive_own_messages,
                "name": node_name,
            }
            self._link = WireLink(name, host, port, hello, self._rx.put, self._remote_closed)
            self.clock = Clock(self._link.params["clock"])
            self.node_name = self._link.node
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)

    @property
    def medium(self) -> Medium | RemoteMedium:
        """The medium's accounting (``stats()``) and test hooks (``set_state``, ``inject_error_frame``)."""
        return self._medium if self._medium is not None else RemoteMedium(self._link)

    @property
    def state(self) -> BusState:
        """ACTIVE, PASSIVE (error passive) or ERROR (bus off), as the medium's test hook set it."""
        if self._node is not None:
            return self._node.state
        # as a socketcan user knows it: from the controller error frames received (no round trip to
        # the server, which the bus watch's polling would make every few ms while SYNC runs)
        self._link.read_now()
        return self._link.state

    @state.setter
    def state(self, new_state: BusState) -> None:
        raise NotImplementedError("a simwire node's state is set by the medium's test hook (Medium.set_state)")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Queue ``msg`` in this node's transmit FIFO. Full: CanOperationError (ENOBUFS), at once or
        after ``timeout`` seconds without room; bus off: CanOperationError (ENETDOWN)."""
        if self._closed:
            raise can.CanOperationError(f"{self.channel_info}: the bus is closed")
        if self._node is not None:
            self._medium.submit(self._node, msg, timeout=timeout)
        else:
            self._link.send(msg, self._local_time, timeout)

    @property
    def timed_transmit(self) -> bool:
        """This bus can hand frames to the medium's transmit schedule (``send_at``): the wall clock only."""
        return self.clock is Clock.WALL and not self._closed

    @property
    def bus_epoch(self) -> float:
        """Bus time = ``bus_epoch`` + ``time.monotonic()`` (the wall-clock medium's time base)."""
        return self._medium.epoch if self._medium is not None else self._link.epoch

    def send_at(self, msgs: Sequence[can.Message], due: float) -> None:
        """``msgs`` go into this node's transmit FIFO at bus time ``due`` (``bus_epoch`` + monotonic), timed
        by the medium, whatever this process is doing then (``Medium.post_at``: SocketCAN's broadcast
        manager, IXXAT's delayed transmit, esd's scheduling); a full FIFO then drops them, as the broadcast
        manager's timer does. Wall clock only."""
        if self._closed:
            raise can.CanOperationError(f"{self.channel_info}: the bus is closed")
        if self.clock is not Clock.WALL:
            raise WireConfigError("a transmit schedule is timed by the wall-clock medium; lockstep has no time")
        if self._node is not None:
            self._medium.post_at(self._node, list(msgs), due)
        else:
            self._link.post_at(list(msgs), due)

    def cancel_scheduled(self) -> None:
        """This node's scheduled frames not yet due are dropped (the broadcast manager's TX_DELETE)."""
        if self._closed or self.clock is not Clock.WALL:
            return
        if self._node is not None:
            self._medium.cancel_posts(self._node)
        else:
            with contextlib.suppress(can.CanError):  # a closed link: the node left, its frames with it
                self._link.cancel_timed()

    def accept_only(self, accepts: Callable[[int], bool] | None) -> bool:
        """A receive filter the medium applies before a frame reaches this node's queue, as a CAN
        controller's acceptance filter or SocketCAN's CAN_RAW_FILTER does in the kernel: the frames it
        refuses still take their time on the wire, but never wake this bus's reader. ``accepts(can_id)``
        is asked at every frame (a live filter: what a canopen Network subscribes to now); None:
        every frame. In-process media only (False: a remote bus receives every frame)."""
        if self._node is None:
            return False
        self._node.accepts = accepts
        return True

    def coalesced(self) -> AbstractContextManager[None]:
        """Frames this thread sends inside it reach a remote medium in one write (``WireLink.coalesce``);
        each is queued, counted and refused as by ``send``. In-process (nothing to write): no effect."""
        if self._link is None or not self._link.pipelined:
            return contextlib.nullcontext()
        return self._link.coalesce()

    def _send_periodic_internal(
        self,
        msgs: Sequence[can.Message] | can.Message,
        period: float,
        duration: float | None = None,
        autostart: bool = True,
        modifier_callback: Callable[[can.Message], None] | None = None,
    ) -> can.broadcastmanager.CyclicSendTaskABC:
        """One frame, no end, no modifier, on an in-process wall-clock medium: timed by the medium
        itself, as SocketCAN's broadcast manager times it in the kernel (each frame queued at its due
        bus time, heard by this node too). Anything else: python-can's thread of its own."""
        one = [msgs] if isinstance(msgs, can.Message) else list(msgs)
        timed_there = self._node is not None or (self._link is not None and self._cyclic_by_medium)
        if not timed_there or self.clock is not Clock.WALL or len(one) != 1 or duration or modifier_callback:
            return super()._send_periodic_internal(msgs, period, duration, autostart, modifier_callback)
        task: can.broadcastmanager.RestartableCyclicTaskABC
        if self._node is not None:
            task = WireCyclicTask(self._medium, self._node, one[0], period)
        else:
            task = RemoteCyclicTask(self._link, one[0], period)
        if autostart:
            task.start()
        return task

    def taken_until(self, delivered: float) -> float:
        """The bus time up to which this bus's reader has taken in (and its listeners handled) every
        frame delivered to it by ``delivered``: before the end of the frame in its reader's hands, or
        of the oldest one waiting in its queue (a canopen Notifier handles a frame between two reads)."""
        until = delivered
        in_hand = self._in_hand
        if in_hand is not None:
            until = min(until, in_hand)
        with contextlib.suppress(IndexError):
            until = min(until, self._waiting[0] - END_MARGIN_S)
        return until

    def _arrive(self, msg: can.Message) -> None:
        """The in-process medium delivers a frame to this node (under its lock: in bus order)."""
        self._waiting.append(msg.timestamp)
        self._rx.put(msg)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._closed:
            raise can.CanOperationError(f"{self.channel_info}: the bus is closed")
        self._in_hand = None  # the reader came back: what it took last is handled
        try:
            msg = self._rx.get(timeout=timeout)
        except queue.Empty:
            return None, False
        if msg is _CLOSED:
            self._rx.put(_CLOSED)
            raise can.CanOperationError(f"{self.channel_info}: the bus is closed")
        if self._node is not None:
            with contextlib.suppress(IndexError):
                self._waiting.popleft()
        if msg.is_rx and msg.timestamp > self._local_time:
            self._local_time = msg.timestamp
            if self._node is not None and self.clock is Clock.LOCKSTEP:
                self._medium.received(self._node, msg.timestamp)
        self._in_hand = msg.timestamp - END_MARGIN_S
        return msg, False

    def _remote_closed(self) -> None:
        self._rx.put(_CLOSED)

    def shutdown(self) -> None:
        if self._closed:
            return
        self._closed = True
        super().shutdown()
        if self._medium is not None:
            self._medium.detach(self._node)
            release_medium(self._name)
        else:
            self._link.close()
        self._rx.put(_CLOSED)

    @staticmethod
    def _detect_available_configs() -> list[AutoDetectedConfig]:
        return [{"interface": "simwire", "channel": name} for name in open_channels()]


class WireCyclicTask(can.broadcastmanager.RestartableCyclicTaskABC):
    """A cyclic send the wall-clock medium times (``Medium.add_cyclic``)."""

    def __init__(self, medium: Medium, node: Node, msg: can.Message, period: float) -> None:
        super().__init__(msg, period)
        self._medium = medium
        self._node = node
        self._msg = msg
        self._cyclic: Cyclic | None = None

    def start(self) -> None:
        if self._cyclic is None:
            self._cyclic = self._medium.add_cyclic(self._node, self._msg, self.period)

    def stop(self) -> None:
        if self._cyclic is not None:
            self._medium.remove_cyclic(self._cyclic)
            self._cyclic = None


class RemoteCyclicTask(can.broadcastmanager.RestartableCyclicTaskABC):
    """A cyclic send the served wall-clock medium times in its own process (``Medium.add_cyclic``
    through the server), as SocketCAN's broadcast manager times it in the kernel, not in this process."""

    def __init__(self, link: WireLink, msg: can.Message, period: float) -> None:
        super().__init__(msg, period)
        self._link = link
        self._msg = msg
        self._task: int | None = None
        self.started: float | None = None  # the first frame's due time, on ``time.monotonic()``

    def start(self) -> None:
        if self._task is None:
            m = self._msg
            self.started = time.monotonic()  # when asked, as the kernel's timer starts at the syscall
            start = self._link.epoch + self.started  # the same instant on the medium's bus time
            self._task = self._link.call(
                "add_cyclic",
                can_id=m.arbitration_id,
                data=bytes(m.data).hex(),
                extended=m.is_extended_id,
                period=self.period,
                start=start,
            )

    def stop(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            with contextlib.suppress(can.CanError, ValueError):  # a closed link: the node left, its sends with it
                self._link.call("remove_cyclic", task=task)
