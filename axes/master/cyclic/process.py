"""The master's side of the cyclic process (``axes.master.cyclic.loop``): start it, hand a run over, follow it.

With ``bus.cyclic_process`` on the wall clock, ``CellBus`` starts a child process that opens the cell's
interface as a node of its own and, during a run, sends SYNC, the time stamp, the fixed-period
setpoints and the EPOS2 records, and quick stops every drive where it cannot go on. The master's
process keeps everything else: configuration, the start (checks, enables, preload, start words), the
decisions (halt, stop, end), the watch over answers, EMCY and heartbeats. The interface between the two
is narrow:

- ``hand_over(feeders, profiles, allowance)`` just before the start SYNC: each feeder's records, where
  it stands, how its frames are packed (``Profile.frame_packer``) and, for an axis without a ramp of its
  own, its stop ramp's limits; the child builds the same feeder classes from them (``axes.master.group.feeder``).
- ``produce(clock, production)``: the child sends the start SYNC and those after it; the master counts
  each SYNC it hears (``SyncClock.heard``), so the drives' answers are counted as before, and the
  master's feeders mirror the child's (their ``next`` from the shared progress array: ``mirror``).
- ``halt(quick)``, ``stop()``, ``quick_stop(nodes)``: one pipe message each, no wait.
- ``hold(t0, grid)`` then ``splice(changes)``: a change of the running program (``axes.master.splice``: an on-path
  stop, a pause, an override); the child holds back every record ending after t0 and answers where its feeders
  stand (the one message the master waits for), then replaces the records from there as the master's mirrors do.
- faults the child sees (a SYNC or setpoint not sent, a gap, a record refused below the FIFO's
  reserve) come back through the pipe and are reported on the bus as any other (``CellBus.report``).

The master's own frames (SDO, controlwords, heartbeat) keep its transmit queue; a full queue there
cannot hold SYNC up. Lockstep (the simulation's virtual clock) never uses it: there SYNC waits for the
answers, and nothing depends on the wall clock.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import queue
import threading
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.subscriptions import subscribe, unsubscribe
from pvtflow.axes.drive.config import interface_times_sync, shared_interface, wire_options
from pvtflow.axes.drive.objects import SYNC_COB_ID
from pvtflow.axes.master.bus.faults import BusError, BusFault, FaultKind
from pvtflow.axes.master.cyclic.loop import (
    MAX_FEEDS,
    PROGRESS_COUNT,
    PROGRESS_FEEDERS,
    CycleSpec,
    CycleTiming,
    FeedSpec,
    serve_cyclic,
)
from pvtflow.axes.master.group.feeder import BufferFeeder, Feeder, RecordAllowance, SetpointFeeder

if TYPE_CHECKING:
    from pvtflow.axes.drive.config import AxisConfig, BusConfig
    from pvtflow.axes.drive.objects import PdoLayout
    from pvtflow.axes.master.bus.faults import FaultCallback
    from pvtflow.axes.master.bus.network import LoggingNetwork
    from pvtflow.axes.master.bus.sync import SyncClock


class HandedLink(Protocol):
    node_id: int


class HandedProfile(Protocol):
    """What the hand-over reads of a drive profile (``axes.master.profiles.base.Profile``): its RPDOs, its
    node, how its frames are packed, whether it ramps by itself, its axis."""

    rpdos: Sequence[PdoLayout]
    link: HandedLink
    config: AxisConfig

    @property
    def ramps_by_itself(self) -> bool: ...

    def frame_packer(self, cob_id: int) -> Any: ...


log = logging.getLogger("pvtflow.bus")

START_TIMEOUT_S = 30.0  # a fresh interpreter importing numpy and python-can on a loaded host


class CyclicProcess:
    """The child that runs the cyclic path of one cell's bus (module docstring): its config, network, the
    report of its faults and its SYNC clock."""

    def __init__(self, config: BusConfig, network: LoggingNetwork, report: FaultCallback, sync: SyncClock) -> None:
        self.config = config
        self.network = network
        self.report = report
        self.sync = sync
        context = multiprocessing.get_context("spawn")  # never fork a process with threads running
        self.progress = context.RawArray("q", 2 + MAX_FEEDS)
        self._conn, child = context.Pipe()
        kwargs: dict[str, object] = {"interface": config.interface, "channel": config.channel}
        kwargs.update(wire_options(config, clock=Clock.WALL))
        kwargs["receive_own_messages"] = True
        if interface_times_sync(config) and config.interface == "simwire":  # the served medium times SYNC, as a kernel
            kwargs["cyclic_by_medium"] = True
        self.process = context.Process(
            target=serve_cyclic,
            args=(
                child,
                kwargs,
                self.progress,
                config.sync_priority,
                config.tx_retry_ms / 1000.0,
                config.quick_stop_confirm_ms / 1000.0,
            ),
            name="pvtflow-cyclic",
            daemon=True,
        )
        self._child_conn = child
        self._send_lock = threading.Lock()
        self._feeders: list[Feeder] = []
        self._spec: CycleSpec | None = None
        self._runs = 0
        self.producing = False
        self._on_echo = None
        self._reader: threading.Thread | None = None
        self.last_timing: CycleTiming | None = None  # the last run's, as the child measured it
        # the child's last quick stop of its own: (why, nodes that confirmed, nodes sent NMT stop)
        self.last_quick_stop: tuple[str, list[int], list[int]] | None = None
        self._held: queue.Queue[tuple[Any, ...]] = queue.Queue()  # the child's answers to ``hold``
        self._holds = 0
        self._extended: queue.Queue[tuple[int, bool]] = queue.Queue()  # the child's answers to ``extend``
        self._extends = 0

    def open(self) -> CyclicProcess:
        config = self.config
        if not shared_interface(config.interface, config.channel):
            self._conn.close()
            self._child_conn.close()
            raise BusError(
                f"bus.cyclic_process needs an interface another process can open as a node of its own "
                f"(socketcan, or a simwire channel served by `pvtflow sim`), not {config.interface}:{config.channel}"
            )
        self.process.start()
        self._child_conn.close()
        if not self._conn.poll(START_TIMEOUT_S):
            self.close()
            raise BusError(f"the cyclic process did not start within {START_TIMEOUT_S:g} s")
        try:
            first = self._conn.recv()
        except (EOFError, OSError):
            first = ("error", f"it ended before it was ready (exit code {self.process.exitcode})")
        if first[0] != "ready":
            self.close()
            raise BusError(f"the cyclic process cannot open the bus: {first[1]}")
        self._reader = threading.Thread(target=self._read, name="pvtflow-cyclic-reports", daemon=True)
        self._reader.start()
        return self

    def _tell(self, *message: object) -> None:
        with self._send_lock, contextlib.suppress(OSError, ValueError):
            self._conn.send(message)

    def _read(self) -> None:
        """The child's reports: faults become the bus's (the group halts or quick stops on them)."""
        while True:
            try:
                message = self._conn.recv()
            except (EOFError, OSError, TypeError):  # TypeError: the handle closed under the read (close)
                if self.producing:
                    self.report(BusFault(FaultKind.SYNC_STOPPED, None, "the cyclic process ended"))
                return
            if message[0] == "fault":
                _, kind, node_id, text, code = message
                self.report(BusFault(FaultKind(kind), node_id, text, code))
            elif message[0] == "timing":
                _, late_us, echo_us, unstamped, refused, followed_us, held = message
                self.last_timing = CycleTiming(late_us, echo_us, unstamped, refused, followed_us, held)
            elif message[0] == "held":
                self._held.put(message[1:])
            elif message[0] == "extended":
                self._extended.put((int(message[1]), bool(message[2])))
            elif message[0] == "note":
                log.warning("cyclic process: %s", message[1])
            elif message[0] == "quick_stopped":
                _, reason, confirmed, nmt = message
                self.last_quick_stop = (reason, confirmed, nmt)
                log.warning("cyclic process quick stop (%s): confirmed by %s, NMT stop to %s", reason, confirmed, nmt)

    # --- a run -----------------------------------------------------------------------------------
    def hand_over(
        self, feeders: Sequence[Feeder], profiles: Sequence[HandedProfile], allowance: RecordAllowance, max_gap_s: float
    ) -> None:
        """The run's feeders as they stand before the start SYNC (after the preload and the start
        setpoints): the child goes on from there."""
        if len(feeders) > MAX_FEEDS:
            raise BusError(f"the cyclic process follows at most {MAX_FEEDS} axes")
        specs = []
        for feeder, profile in zip(feeders, profiles, strict=True):
            cob = profile.rpdos[0].cob_id(profile.link.node_id, receive=True)
            spec = FeedSpec(
                node_id=profile.link.node_id,
                records=feeder.records,
                packer=profile.frame_packer(cob),
                next=feeder.next,
                enabled=feeder.enabled,
            )
            if isinstance(feeder, SetpointFeeder):
                spec.lead = feeder.lead
                if not profile.ramps_by_itself:
                    spec.braking = (profile.config.limits, profile.config.scaling)
            elif isinstance(feeder, BufferFeeder):
                spec.buffer, spec.capacity, spec.lookahead_ms = feeder.buffer, feeder.capacity, feeder.lookahead_ms
                spec.hold_end_ms = feeder.hold_end_ms
            specs.append(spec)
        self._runs += 1
        clock = self.sync
        self._feeders = list(feeders)
        for feeder in self._feeders:  # from the start SYNC on, the child sends; these only mirror it
            feeder.hand_over()
        self._spec = CycleSpec(
            run=self._runs,
            period_ms=clock.period_ms,
            start_count=clock.count + 1,
            stamp_cob_id=clock.time_stamp_cob_id,
            max_gap_s=max_gap_s,
            records_per_sync=allowance.per_sync,
            tx_queue_frames=self.config.tx_queue_frames,
            interface_sync=interface_times_sync(self.config),
            max_lookahead_ms=self.config.max_lookahead_ms,
            feeds=specs,
        )

    @property
    def handed_over(self) -> bool:
        return self._spec is not None

    def produce(self, clock: SyncClock, production: int) -> None:
        """The child starts SYNC with the run handed over; each SYNC heard is counted here."""
        spec, self._spec = self._spec, None
        assert spec is not None
        spec.start_count = clock.count + 1

        def on_echo(can_id: int, data: bytearray, timestamp: float) -> None:
            self.mirror()
            clock.heard(production)

        self._unsubscribe()
        self._on_echo = on_echo
        subscribe(self.network, SYNC_COB_ID, on_echo)
        self.producing = True
        self._tell("start", spec)

    def mirror(self) -> None:
        """The master's feeders where the child's stand (records sent)."""
        progress = self.progress
        for i, feeder in enumerate(self._feeders):
            feeder.sent_elsewhere(int(progress[PROGRESS_FEEDERS + i]))

    @property
    def syncs_sent(self) -> int:
        return int(self.progress[PROGRESS_COUNT])

    def hold(self, t0_ms: float, grid_ms: int, timeout_s: float) -> tuple[float, list[int]]:
        """A change of the running program (``axes.master.splice``): the child sends no record ending after
        ``t0_ms`` (moved past what it has sent, on the grid ``grid_ms``) until ``splice``; (that t0, each feeder's
        next record there). TimeoutError where it does not answer within ``timeout_s`` (then ``splice(None)``)."""
        self._holds += 1
        number = self._holds
        self._tell("hold", number, float(t0_ms), int(grid_ms))
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                answer = self._held.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                why = f"the cyclic process did not answer a hold within {timeout_s * 1000:.0f} ms"
                raise TimeoutError(why) from None
            if answer[0] == number:  # an answer to an earlier hold that timed out is dropped
                for feeder, sent in zip(self._feeders, answer[2], strict=True):
                    feeder.sent_elsewhere(int(sent))
                return float(answer[1]), [int(n) for n in answer[2]]

    def splice(self, changes: Sequence[tuple[int, Any]] | None) -> None:
        """Each feeder's new records from its record ``first`` on, ``(first, rows)`` in axis order, to the child
        (its feeders held by ``hold``); None: none, the held records go out as they were."""
        self._tell("splice", None if changes is None else [(int(f), r) for f, r in changes])

    def extend(self, records: Sequence[Any], timeout_s: float) -> bool:
        """A queued program (``axes.master.run_queue``): each feeder's next records, in axis order, joined to the
        child's feeders where every one can still take them (True), else nothing changed there (False).
        TimeoutError where it does not answer within ``timeout_s`` (its answer, when it comes, is dropped)."""
        self._extends += 1
        number = self._extends
        self._tell("extend", number, list(records))
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                answer, joined = self._extended.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                raise TimeoutError(
                    f"the cyclic process did not answer a queued program within {timeout_s * 1000:.0f} ms"
                ) from None
            if answer == number:
                return joined

    def halt(self, quick: bool) -> None:
        self._tell("halt", quick)

    def quick_stop(self, reason: str, node_ids: Sequence[int]) -> None:
        """The SDO quick stop requests from the child's queue too (never behind the master's frames)."""
        self._tell("quick_stop", reason, list(node_ids))

    def stop(self) -> None:
        if self.producing:
            self.producing = False
            self._tell("stop")
        self._unsubscribe()

    def _unsubscribe(self) -> None:
        if self._on_echo is not None:
            unsubscribe(self.network, SYNC_COB_ID, self._on_echo)
            self._on_echo = None

    def close(self) -> None:
        self.stop()
        self._tell("close")
        self.process.join(2.0)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(2.0)
        with contextlib.suppress(OSError):
            self._conn.close()
