"""The cell's CAN bus as the master sees it: python-can bus, canopen Network, NMT, SYNC, consumers, log.

SYNC has two modes (``CellBus(lockstep=...)``):

- real time: SYNC every ``sync_period_ms`` of wall-clock time, followed by the 0x1013 time stamp and
  the frames that must follow every SYNC (a fixed-period drive's setpoints: ``add_sender``), so a
  setpoint is on the bus a whole period before the SYNC that validates it. Where the interface sends
  SYNC cyclically by itself (python-can's ``send_periodic`` not falling back on its
  ``ThreadBasedCyclicSendTask``: socketcan's broadcast manager), it does, and a master thread follows
  each SYNC the bus hears. Elsewhere (virtual, pcan) a master thread sends SYNC on absolute
  deadlines: a deadline passed by more than half a period is skipped and counted (``skipped``),
  never sent late in a burst (a fixed-period drive would take two setpoints in one period), and no
  SYNC goes out within half a period of the one before. The thread asks for SCHED_FIFO
  (``BusConfig.sync_priority``; not permitted: one warning, normal priority).
  A gap longer than the drives ride out is reported (``FaultKind.SYNC_GAP``, the gap in ms), before
  the thread sends the SYNC after it (the halt the report causes comes first): the
  rule is ``BusConfig.max_sync_gap_periods`` when the cell sets it, else the profiles' (``Profile.
  max_sync_gap_ms``): 2 periods for a drive that takes one setpoint per SYNC (one SYNC skipped
  makes it hold one period, more would be a jump), and for the EPOS2, which runs its records on
  its own clock and only loses its feed in a gap, the time of its program's shortest run of
  ``underflow_warning`` records (the FIFO reserve its feeder keeps). The SYNC thread never ends
  silently: a frame the interface refuses past ``tx_retry_ms`` of retries (``TX_FAILED``) or any
  other error (``SYNC_STOPPED``) is reported, and the group then quick stops every axis by SDO
  (``axes.quick_stop``), which does not need SYNC.
- lockstep (simulation): the next SYNC goes out once every drive has answered the previous one with
  its synchronous TPDO and the SYNC listeners (the feeders) have run (a drive whose status TPDO goes
  out every n SYNCs is waited for on the SYNCs it owes an answer for: ``SyncClock.expect``). Drive
  time advances one period per SYNC, so a simulated cell runs as fast as the bus and the CPU allow,
  and nothing depends on a sleep. The same answer counting runs in real time and gives the SYNC count there too.

Failures are watched by one thread: heartbeat loss (no heartbeat for ``heartbeat_ms *
heartbeat_timeout_factor``), lost SYNC (no answered SYNC for ``lost_sync_timeout_s``), NMT state
change of a node, error frames (``BUS_WARNING``, at most once a second) and python-can's
``bus.state`` (error passive: ``BUS_WARNING``; bus-off: ``BUS_OFF``, nothing can be sent). EMCY
frames are reported as they arrive (the CAN ones in their words: 0x8110, 0x8120, 0x8140). The
watchdog polls: wall-clock time is used only to *detect* a failure, never to pace the motion.

The master has a heartbeat of its own (``axes/heartbeat.py``), started and stopped with the bus,
that every drive watches (0x1016) and stops on when it stops (0x6007).
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import struct
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import can
import canopen
from canopen.emcy import EmcyError
from canopen.objectdictionary import ObjectDictionary

from axes import collector
from axes.config import BusConfig, wire_options
from axes.heartbeat import MasterHeartbeat
from axes.objects import CAN_EMCY_WORDS, NMT_STATE_OPERATIONAL, SYNC_COB_ID, TIME_STAMP_COB_ID
from axes.quick_stop import QuickStop, quick_stop_all
from axes.subscriptions import subscribe, unsubscribe

# How long the master waits for one SDO answer. python-canopen's 0.3 s is tight for a simulated cell
# on a loaded 2-core host (a drive's thread may not run for that long); a real drive answers within
# milliseconds, so a longer wait only delays the report of a drive that is really gone.
SDO_RESPONSE_TIMEOUT_S = 1.0
NMT_OPERATIONAL = 0x01
NMT_STOPPED = 0x02
NMT_PRE_OPERATIONAL = 0x80
NMT_RESET_COMMUNICATION = 0x82
NMT_STATE_PRE_OPERATIONAL = 127
NMT_STATE_BOOT_UP = 0  # the boot-up message: a heartbeat frame with state 0
SWITCH_INTERVAL_S = 0.0001  # the interpreter hands the GIL on at least this often while a bus is open
TX_RETRY_PAUSE_S = 0.0002  # between two tries of a frame the interface refused
ERROR_FRAME_REPORT_S = 1.0  # error frames are reported at most this often (with the count since the last report)

log = logging.getLogger("pvtflow.bus")


class BusError(RuntimeError):
    """The bus cannot be opened or a frame cannot be sent (one clear line for the user)."""


class FaultKind(StrEnum):
    """What the bus saw fail."""

    EMCY = "emcy"  # a node sent an emergency
    HEARTBEAT = "heartbeat"  # a node's heartbeat stopped
    NMT = "nmt"  # a node left OPERATIONAL (or booted)
    LOST_SYNC = "lost_sync"  # a node stopped answering SYNC
    SYNC_GAP = "sync_gap"  # the master sent no SYNC for longer than the drives ride out (the gap in ms)
    SYNC_STOPPED = "sync_stopped"  # the thread that sends SYNC ended by an error
    TX_FAILED = "tx_failed"  # the interface refused a frame past the retries (queue full, an error)
    BUS_OFF = "bus_off"  # the master's CAN controller is bus-off: it can send nothing
    BUS_WARNING = "bus_warning"  # error frames on the bus, or the master's controller error passive

    @property
    def warning(self) -> bool:
        """Reported, but the motion goes on: the bus still carries every frame."""
        return self is FaultKind.BUS_WARNING

    @property
    def sync_failed(self) -> bool:
        """The master cannot keep SYNC: a halt must not wait for one (``axes.quick_stop``)."""
        return self in (FaultKind.SYNC_GAP, FaultKind.SYNC_STOPPED, FaultKind.TX_FAILED, FaultKind.BUS_OFF)


@dataclass(frozen=True)
class BusFault:
    """A failure seen on the bus."""

    kind: FaultKind
    node_id: int | None
    message: str
    code: int = 0


FaultCallback = Callable[[BusFault], None]
SyncCallback = Callable[[int], None]
DEFAULT_MAX_GAP_PERIODS = 2.0  # a fixed-period drive misses a setpoint in a longer gap (module docstring)


class FrameRecorder(can.Listener):
    """Counts every frame (sent and received) and, with a log file, writes it through can.Logger."""

    def __init__(self, path: str | Path | None = None) -> None:
        self._lock = threading.Lock()
        self._logger: can.Listener | None = can.Logger(str(path)) if path is not None else None
        # BLF and ASC store a channel NUMBER (python-can takes the name's trailing digits): a
        # name like "cell-20260401" would not fit, and one cell is one bus anyway
        self._numbered = path is not None and Path(path).suffix.lower() in (".blf", ".asc")
        self.frames = 0
        self.frames_sent = 0
        self.taps: list[Callable[[can.Message], None]] = []  # see every frame (benchmarks, monitors)

    def on_message_received(self, msg: can.Message) -> None:
        with self._lock:
            self.frames += 1
            if self._logger is not None:
                self._logger.on_message_received(self._for_log(msg))
            for tap in self.taps:
                tap(msg)

    def _for_log(self, msg: can.Message) -> can.Message:
        if not self._numbered:
            return msg
        number = can.util.channel2int(msg.channel)
        if number is not None and 0 <= number < 0xFFFF:
            return msg
        return can.Message(
            timestamp=msg.timestamp,
            arbitration_id=msg.arbitration_id,
            is_extended_id=msg.is_extended_id,
            is_remote_frame=msg.is_remote_frame,
            is_error_frame=msg.is_error_frame,
            dlc=msg.dlc,
            data=msg.data,
            is_rx=msg.is_rx,
            channel=0,
        )

    def on_message_sent(self, msg: can.Message) -> None:
        with self._lock:
            self.frames_sent += 1
        self.on_message_received(msg)

    def stop(self) -> None:
        with self._lock:
            if self._logger is not None:
                self._logger.stop()
                self._logger = None


class RecordingNetwork(canopen.Network):
    """A canopen Network whose own frames go to the recorder too (a bus does not hear itself)."""

    def __init__(self, bus: can.BusABC | None = None, recorder: FrameRecorder | None = None) -> None:
        super().__init__(bus)
        self.recorder = recorder
        self.channel_name: str | None = None  # written into the log with the frames we send
        self.tx_retry_s = 0.002  # a frame the interface refuses is tried again this long (BusConfig.tx_retry_ms)
        self._patience = threading.local()  # a longer bound for this thread's frames (``patient``)
        self.tx_retries = 0  # tries that failed, all frames together

    @contextlib.contextmanager
    def patient(self, seconds: float) -> Iterator[None]:
        """Frames this thread sends meanwhile are tried again for up to ``seconds``: for bulk frames
        that nothing waits on in the meantime (a preload before the first SYNC), which a full
        transmit queue only delays by the wire time of what is ahead of them."""
        previous = getattr(self._patience, "seconds", None)
        self._patience.seconds = seconds
        try:
            yield
        finally:
            self._patience.seconds = previous

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        if not self.bus:
            raise RuntimeError("Not connected to CAN bus")
        msg = can.Message(
            is_extended_id=can_id > 0x7FF,
            arbitration_id=can_id,
            data=data,
            is_remote_frame=remote,
            is_rx=False,
            channel=self.channel_name,
        )
        deadline: float | None = None
        wait: float | None = None  # the first try does not wait: a retry lets the queue drain meanwhile
        while True:
            try:
                with self.send_lock:
                    msg.timestamp = time.time()
                    self.bus.send(msg, timeout=wait)
                break
            except (can.CanOperationError, OSError) as exc:  # a full transmit queue (ENOBUFS), a refusing controller
                now = time.monotonic()
                if deadline is None:
                    deadline = now + (getattr(self._patience, "seconds", None) or self.tx_retry_s)
                self.tx_retries += 1
                if now >= deadline:
                    bound = getattr(self._patience, "seconds", None) or self.tx_retry_s
                    raise can.CanOperationError(
                        f"frame 0x{can_id:03X} not sent within {bound * 1000:.1f} ms: {exc}"
                    ) from exc
                time.sleep(TX_RETRY_PAUSE_S)
                wait = max(deadline - time.monotonic(), 0.0)
        if self.recorder is not None:
            self.recorder.on_message_sent(msg)


_realtime_warned = False


def ask_realtime(priority: int) -> bool:
    """SCHED_FIFO at ``priority`` for the calling thread (Linux applies it to the thread, not the
    process). Not permitted (EPERM), or no such call on this OS: one warning per process, and the
    thread runs at normal priority. ``priority`` 0: not asked."""
    global _realtime_warned
    if priority <= 0:
        return False
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return True
    except (AttributeError, OSError) as exc:  # AttributeError: no SCHED_FIFO on this OS
        if not _realtime_warned:
            _realtime_warned = True
            log.warning(
                "SYNC runs at normal priority: SCHED_FIFO %d not granted (%s); permit it with root, "
                "CAP_SYS_NICE or an rtprio limit (README, the wall clock), or set sync_priority: 0",
                priority,
                exc,
            )
        return False


def native_cyclic_task(bus: can.BusABC, msg: can.Message, period_s: float) -> can.broadcastmanager.CyclicTask | None:
    """A cyclic send of ``msg`` that the interface times by itself (socketcan: the kernel's broadcast
    manager), not started yet; None where python-can would fall back on a thread of its own
    (``ThreadBasedCyclicSendTask``: virtual, pcan, ...), which is no better than the SYNC thread."""
    if type(bus)._send_periodic_internal is can.BusABC._send_periodic_internal:
        return None
    try:
        task = bus.send_periodic(msg, period_s, autostart=False)
    except (can.CanError, NotImplementedError, OSError, TypeError):
        return None
    if isinstance(task, can.broadcastmanager.ThreadBasedCyclicSendTask):
        task.stop()
        return None
    return task


class SyncClock:
    """SYNC producer and counter of the drives' answers (see the module docstring for the modes).

    ``count`` is the number of SYNCs sent, ``answered`` the number every expected node has answered.
    Listeners get the number of the SYNC just answered; in lockstep they run before the next SYNC.
    On the wall clock: ``skipped`` periods whose SYNC was skipped (never sent late), ``longest_gap_s``
    the longest time between two SYNCs, ``max_gap_s`` the gap that is reported (``FaultKind.SYNC_GAP``),
    ``realtime`` whether the sending thread got SCHED_FIFO, ``native`` whether the interface sends SYNC.
    """

    def __init__(
        self,
        bus: CellBus,
        period_ms: float,
        lockstep: bool,
        time_stamp_cob_id: int | None = None,
        priority: int = 0,
        max_gap_periods: float = DEFAULT_MAX_GAP_PERIODS,
    ):
        self.bus = bus
        self.period_ms = period_ms
        self.lockstep = lockstep
        self.time_stamp_cob_id = time_stamp_cob_id
        self.priority = priority
        self.max_gap_s = max_gap_periods * period_ms / 1000.0
        self.count = 0
        self.answered = 0
        self.skipped = 0
        self.longest_gap_s = 0.0
        self.realtime: bool | None = None  # None: no SYNC thread has run yet
        self.native = False
        self.last_progress = time.monotonic()
        self._answers: dict[int, int] = {}  # cob id -> the last SYNC its answers stand for
        self._every: dict[int, int] = {}  # cob id -> the SYNCs one answer stands for (transmission type n)
        self._completing = False  # _complete is running (it sends the next lockstep SYNC itself)
        self._listeners: list[SyncCallback] = []
        self._senders: list[SyncCallback] = []  # run right after each SYNC goes out, by whoever sends it
        self.lock = threading.RLock()  # held while SYNC listeners run and while a SYNC goes out
        self._answered_changed = threading.Condition(self.lock)
        self.last_sent = time.monotonic()  # when the last SYNC went out
        self._previous: float | None = None  # when this production's last SYNC went out (gaps)
        self._running = False
        self._production = 0  # which start() the producing thread serves: a stale one stops by itself
        self._task: can.broadcastmanager.CyclicTask | None = None  # the interface's own cyclic SYNC
        self._echo = threading.Condition(threading.Lock())
        self._echoes = 0  # SYNC frames the interface sent and the bus heard (native mode)
        self._collector_held = False  # this clock holds the cyclic collector off (wall clock, running)
        self._echo_stamp: float | None = None  # native mode: the last SYNC echo's time stamp (bus time)
        self._echo_gap = 0.0  # native mode: the longest gap between SYNC echoes not yet judged
        self._t0_us = time.monotonic_ns() // 1000
        self.hold: Callable[[], None] | None = None  # benchmarks and tests: called before each wall-clock SYNC

    # --- answers ---------------------------------------------------------------------------------
    def expect(self, answers: Iterable[int] | Mapping[int, int]) -> None:
        """The synchronous TPDOs that answer SYNC (one per drive): COB-IDs, or COB-ID -> n for a TPDO
        of transmission type n (``axes.tpdo_rates``), which answers once in every n SYNCs. The master
        takes an answer as standing for the SYNC it arrived after and the n - 1 after that, and, not
        knowing where a drive's SYNC counter stands, a new expectation as standing for the next n - 1:
        never less than the drive's answers cover, so lockstep never waits for an answer a drive does
        not owe (it waits at the latest on the n-th SYNC, which every drive has answered by then).
        Call it after the links have subscribed their TPDO decoders: an answer is then decoded
        before it is counted, so whoever waits for a SYNC's answers (``wait_answered``) reads what
        the drives said on it."""
        every = dict(answers) if isinstance(answers, Mapping) else dict.fromkeys(answers, 1)
        with self.lock:
            for cob in self._answers:
                unsubscribe(self.bus.network, cob, self._on_answer)
            self._every = every
            self._answers = {cob: self.count + n - 1 for cob, n in every.items()}
            self.answered = self.count
            for cob in self._answers:
                subscribe(self.bus.network, cob, self._on_answer)

    def _done(self) -> int:
        """The last SYNC every drive has answered or owes no answer for (never past the SYNCs sent)."""
        return min(min(v, self.count) if self._every.get(c, 1) > 1 else v for c, v in self._answers.items())

    def add_listener(self, callback: SyncCallback) -> None:
        self._listeners.append(callback)

    def remove_listener(self, callback: SyncCallback) -> None:
        if callback in self._listeners:
            self._listeners.remove(callback)

    def add_sender(self, callback: SyncCallback) -> None:
        """``callback(n)`` right after SYNC number ``n`` is on the bus, in the thread that sent it and
        before the next SYNC can go out: what must be on the bus before SYNC n + 1 (a fixed-period
        drive's next setpoint) is sent there, never paced by the drives' answers, so the wall clock
        cannot make it late. Keep it to sending precomputed frames."""
        with self.lock:
            self._senders.append(callback)

    def remove_sender(self, callback: SyncCallback) -> None:
        with self.lock:
            if callback in self._senders:
                self._senders.remove(callback)

    def behind(self) -> list[int]:
        """COB-IDs of the answers still missing for the last SYNC sent."""
        with self.lock:
            return [cob for cob, n in self._answers.items() if n < self.count]

    def _on_answer(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            n = self._answers.get(can_id)
            every = self._every.get(can_id, 1)
            if n is None or (self.lockstep and every == 1 and n >= self.count):
                return  # an answer without a SYNC (or a duplicate): nothing to count
            # an answer of type n stands for the last SYNC sent and the n - 1 after it
            self._answers[can_id] = n + 1 if every == 1 else max(n, self.count + every - 1)
            self._answered_changed.notify_all()
            failed = self._complete()
        if failed is not None:
            self.bus.report(failed)

    def _complete(self) -> BusFault | None:
        """Advance ``answered`` to every SYNC answered or owed no answer, run the listeners on it and,
        in lockstep, send the next SYNC (again while no drive owes an answer for it). Called with the
        lock held; a fault to report (after the lock is released) or None."""
        if self._completing:
            return None
        self._completing = True
        done = self.answered
        try:  # a frame a listener cannot send must not end the bus's receive thread
            while True:
                done = self._done()
                if done <= self.answered:
                    return None
                self.answered = done
                self.count = max(self.count, done)
                self.last_progress = time.monotonic()
                for cb in list(self._listeners):
                    cb(done)
                if not (self.lockstep and self._running and self.answered == self.count):
                    return None
                self._transmit()
        except (can.CanError, OSError) as exc:
            self._running = False
            self._production += 1
            return BusFault(FaultKind.TX_FAILED, None, f"after SYNC {done}: {exc}")
        except Exception as exc:
            log.exception("a SYNC listener failed")
            self._running = False
            self._production += 1
            return BusFault(FaultKind.SYNC_STOPPED, None, f"SYNC ended after SYNC {done}: {exc!r}")
        finally:
            self._completing = False

    # --- production ------------------------------------------------------------------------------
    def _transmit(self, sync_frame: bool = True) -> None:
        """SYNC (unless the interface sent it: ``sync_frame`` False), the time stamp, the senders."""
        with self.lock:
            self.count += 1
            now = time.monotonic()
            self.last_sent = now
            if self._previous is not None:
                self.longest_gap_s = max(self.longest_gap_s, now - self._previous)
            self._previous = now
            if sync_frame:
                self.bus.network.send_message(SYNC_COB_ID, b"")
            if self.time_stamp_cob_id is not None:
                stamp = (time.monotonic_ns() // 1000 - self._t0_us) & 0xFFFFFFFF
                self.bus.network.send_message(self.time_stamp_cob_id, struct.pack("<I", stamp))
            for send in self._senders:
                send(self.count)
            if not self._completing and any(n > 1 for n in self._every.values()):
                # drives whose status TPDO goes out every n SYNCs may owe no answer for this one: its
                # listeners run now, in the sending thread, as no answer will bring them
                failed = self._complete()
                if failed is not None:
                    self.bus.report(failed)

    def start(self) -> None:
        """Send the first SYNC now and keep producing (lockstep: on answers; real time: periodic)."""
        with self.lock:
            if self._running:
                return
            self._running = True
            self._previous = None
            with self._echo:
                self._echo_stamp, self._echo_gap = None, 0.0
            self.last_progress = time.monotonic()
            if self.lockstep:
                try:
                    self._transmit()
                except (can.CanError, OSError):
                    self._running = False
                    raise
                if not self._answers:  # nobody to wait for: a single SYNC
                    self._running = False
                return
            production = self._production
            if not self._collector_held:
                collector.hold()  # no collection pause while SYNC runs on the wall clock (axes/collector.py)
                self._collector_held = True
            msg = can.Message(arbitration_id=SYNC_COB_ID, data=b"", is_extended_id=False)
            assert self.bus.network.bus is not None
            self._task = native_cyclic_task(self.bus.network.bus, msg, self.period_ms / 1000.0)
            self.native = self._task is not None
        target = self._follow if self.native else self._produce
        name = "pvtflow-sync-follow" if self.native else "pvtflow-sync"
        threading.Thread(target=self._guarded, args=(target, production), name=name, daemon=True).start()

    def _producing(self, production: int) -> bool:
        """Still the production this thread was started for (called with the lock held)."""
        return self._running and self._production == production

    def _guarded(self, target: Callable[[int], None], production: int) -> None:
        """The SYNC thread never ends silently: a send that fails past its retries, or any error,
        ends the production and is reported (the motion halts without SYNC: ``axes.quick_stop``)."""
        self.realtime = ask_realtime(self.priority)
        try:
            target(production)
        except (can.CanError, OSError) as exc:
            self._fail(production, BusFault(FaultKind.TX_FAILED, None, f"SYNC {self.count + 1} not sent: {exc}"))
        except Exception as exc:
            log.exception("the SYNC thread failed")
            self._fail(production, BusFault(FaultKind.SYNC_STOPPED, None, f"the SYNC thread ended: {exc!r}"))

    def _fail(self, production: int, fault: BusFault) -> None:
        with self.lock:
            if not self._producing(production):
                return  # stopped meanwhile: nothing of this production is wanted any more
            self._running = False
            self._production += 1
        self.bus.report(fault)

    def _gap(self, gap_s: float) -> None:
        """Report a gap the drives do not ride out (called without the lock)."""
        if gap_s > self.max_gap_s:
            self.bus.report(
                BusFault(
                    FaultKind.SYNC_GAP,
                    None,
                    f"no SYNC for {gap_s * 1000:.1f} ms (the drives ride out {self.max_gap_s * 1000:.1f} ms)",
                    round(gap_s * 1000),
                )
            )

    def _produce(self, production: int) -> None:
        """SYNC on absolute deadlines; a deadline passed by more than half a period is skipped."""
        period = self.period_ms / 1000.0
        deadline = time.monotonic()
        judged: float | None = None  # the SYNC whose gap was reported before the next went out
        while True:
            if self.hold is not None:
                self.hold()
            with self.lock:  # never a SYNC after stop(): it is judged under the lock stop() takes
                if not self._producing(production):
                    return
                now = time.monotonic()
                # a gap beyond what the drives ride out is reported before another SYNC goes out, so
                # that the halt it causes comes first (a stalled master: the process was held)
                overdue = None
                if self._previous is not None and self._previous != judged and now - self._previous > self.max_gap_s:
                    overdue, judged = now - self._previous, self._previous
            if overdue is not None:
                self._gap(overdue)
                continue
            with self.lock:
                if not self._producing(production):
                    return
                now = time.monotonic()
                late = now - deadline
                if late > period / 2:  # never late in a burst: on to the next deadline not yet half a period past
                    missed = math.ceil((late - period / 2) / period)
                    self.skipped += missed
                    deadline += missed * period
                gap = None
                # not before its deadline, nor within half a period of the last SYNC (one sent late)
                due = deadline if self._previous is None else max(deadline, self._previous + period / 2)
                if now >= due:
                    gap = None if self._previous is None or self._previous == judged else now - self._previous
                    self._transmit()
                    deadline += period
                    due = deadline
            if gap is not None:
                self._gap(gap)
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)

    def _on_sync_echo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._echo:
            self._echoes += 1
            if self._echo_stamp is not None:  # the bus's own time stamps: the gap the drives saw
                self._echo_gap = max(self._echo_gap, timestamp - self._echo_stamp)
            self._echo_stamp = timestamp
            self._echo.notify_all()

    def _follow(self, production: int) -> None:
        """The interface sends SYNC: this thread follows each one the bus hears with the time stamp
        and the setpoints. SYNCs that came while it was held are counted, one time stamp and one
        setpoint follow the last (the feeder sends the setpoint due after it)."""
        network = self.bus.network
        with self._echo:
            seen, silent = self._echoes, False  # the SYNCs heard before this production are not its own

        # this production's own subscriber: a follower of the previous production still winding
        # down unsubscribes its own, never this one's
        def on_echo(can_id: int, data: bytearray, timestamp: float) -> None:
            self._on_sync_echo(can_id, data, timestamp)

        subscribe(network, SYNC_COB_ID, on_echo)
        try:
            assert self._task is not None
            if isinstance(self._task, can.broadcastmanager.RestartableCyclicTaskABC):
                self._task.start()
            while True:
                with self._echo:
                    heard = self._echo.wait_for(lambda seen=seen: self._echoes > seen, self.max_gap_s)
                if not heard:  # a held process wakes this thread first: let the receive thread catch up
                    with self._echo:
                        self._echo.wait_for(lambda seen=seen: self._echoes > seen, self.period_ms / 1000.0)
                with self._echo:
                    echoes = self._echoes
                now = time.monotonic()
                gap = None
                with self.lock:
                    if not self._producing(production):
                        return
                    if echoes > seen:
                        self.skipped += echoes - seen - 1  # heard, but not followed one by one
                        self.count += echoes - seen - 1
                        # the interface times SYNC: a gap is between the SYNCs on the bus, not in
                        # this thread's wakes (a held process delays the time stamp, not the SYNC)
                        with self._echo:
                            gap, self._echo_gap = self._echo_gap, 0.0
                        self._transmit(sync_frame=False)
                        seen, silent = echoes, False
                    elif not silent:  # no SYNC heard for the whole gap the drives ride out: once
                        silent = True
                        gap = now - (self._previous if self._previous is not None else now)
                if gap is not None:
                    self._gap(gap)
        finally:
            unsubscribe(network, SYNC_COB_ID, on_echo)

    def step(self) -> dict[int, int]:
        """Send one SYNC by hand, outside production (e.g. the start's check: every drive answers it
        with its synchronous TPDO); what each drive's answer count will be once it has answered,
        for ``wait_answered`` (in real time ``count`` is a wall-clock estimate, not a SYNC's number)."""
        with self.lock:
            sent = self.count + 1
            # a drive of type n > 1 owes an answer only on its every n-th SYNC
            owed = {cob: n + 1 if self._every.get(cob, 1) == 1 else sent for cob, n in self._answers.items()}
            self._transmit()
            return owed

    def wait_answered(self, owed: dict[int, int], timeout_s: float) -> list[int]:
        """Wait until every drive has answered the SYNC ``step`` sent; the COB-IDs of the answers
        still missing then (empty: every drive answered in time)."""

        def missing() -> list[int]:
            return [cob for cob, n in owed.items() if self._answers.get(cob, 0) < n]

        with self.lock:
            self._answered_changed.wait_for(lambda: not missing(), timeout_s)
            return missing()

    def keep_period(self) -> None:
        """Real time: wait until one period after the last SYNC sent, so that the next one (``start``)
        keeps the cell's SYNC period after a SYNC sent by hand. Lockstep: nothing to wait for."""
        if not self.lockstep:
            delay = self.last_sent + self.period_ms / 1000.0 - time.monotonic()
            if delay > 0:
                time.sleep(delay)

    def stop(self) -> None:
        """No SYNC after this returns. The producing thread is not joined: stop() is called from SYNC
        listeners, which hold the lock that thread needs to see it must end (joining there blocked
        the bus's receive thread, and every SDO answer with it, for the join's whole timeout)."""
        with self.lock:
            self._running = False
            self._production += 1
            task, self._task = self._task, None
            held, self._collector_held = self._collector_held, False
        if task is not None:
            task.stop()
        if held:
            collector.release()

    @property
    def running(self) -> bool:
        return self._running


class CellBus:
    """python-can bus + canopen Network of one cell, with NMT, SYNC, heartbeat and EMCY consumers."""

    def __init__(
        self,
        config: BusConfig,
        *,
        lockstep: bool = True,
        can_log: str | Path | None = None,
        lost_sync_timeout_s: float = 1.0,
        time_stamp: bool | None = None,
    ) -> None:
        self.config = config
        self.can_log = can_log
        self.recorder = FrameRecorder(can_log)
        self.network = RecordingNetwork(recorder=self.recorder)
        self.network.channel_name = config.channel
        stamp = config.time_stamp if time_stamp is None else time_stamp
        gap = config.max_sync_gap_periods if config.max_sync_gap_periods is not None else DEFAULT_MAX_GAP_PERIODS
        self.sync = SyncClock(
            self,
            config.sync_period_ms,
            lockstep,
            TIME_STAMP_COB_ID if stamp else None,
            priority=config.sync_priority,
            max_gap_periods=gap,
        )
        self.network.tx_retry_s = config.tx_retry_ms / 1000.0
        self.errors = ErrorFrames()
        self.state = can.BusState.ACTIVE  # the master's controller as python-can last reported it
        self.lost_sync_timeout_s = lost_sync_timeout_s
        self.nodes: dict[int, canopen.RemoteNode] = {}
        self._fault_callbacks: list[FaultCallback] = []
        self._heartbeat_seen: dict[int, float] = {}
        self._heartbeat_state: dict[int, int] = {}
        self._boots: dict[int, int] = {}  # boot-up messages seen per node (NMT reset, power-on)
        self._watched: set[int] = set()
        self._lock = threading.Lock()
        self._watchdog: threading.Thread | None = None
        self._closing = threading.Event()
        self.watch_sync = False
        self._sync_reported = False
        self.master_heartbeat = MasterHeartbeat(self)

    # --- life cycle ------------------------------------------------------------------------------
    def open(self) -> CellBus:
        # The bus is served by threads (SYNC answers, feeders, consumers; in a simulation the drives
        # too) that must get the GIL within a fraction of a SYNC period, not after CPython's 5 ms
        # switch interval: a process with a bus open keeps it at SWITCH_INTERVAL_S (not restored on
        # close: other buses of the process may still be open).
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
        kwargs: dict[str, object] = {"interface": self.config.interface, "channel": self.config.channel}
        kwargs.update(wire_options(self.config, lockstep=self.sync.lockstep))
        try:
            bus = can.Bus(**kwargs)
        except (can.CanError, OSError, ValueError, ImportError) as exc:
            where = f"{self.config.interface}:{self.config.channel}"
            raise BusError(f"cannot open CAN bus {where}: {exc}") from None
        self.network.bus = bus
        self.network.notifier = can.Notifier(bus, [*self.network.listeners, self.recorder, self.errors], 0.1)
        self._closing.clear()
        self._watchdog = threading.Thread(target=self._watch, name="pvtflow-watchdog", daemon=True)
        self._watchdog.start()
        self.master_heartbeat.start()
        return self

    @property
    def is_open(self) -> bool:
        return self.network.bus is not None

    def close(self) -> None:
        self.sync.stop()
        self.master_heartbeat.stop()
        self._closing.set()
        if self._watchdog is not None:
            self._watchdog.join(timeout=2.0)
            self._watchdog = None
        if self.network.bus is not None:
            self.network.disconnect()
        self.recorder.stop()

    def __enter__(self) -> CellBus:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- nodes -----------------------------------------------------------------------------------
    def add_node(self, node_id: int) -> canopen.RemoteNode:
        """A remote node with an empty dictionary: pvtflow addresses objects by index, so the master
        does not need the drive's EDS (any EPOS2, Parker or simulated node will do)."""
        if node_id in self.nodes:
            return self.nodes[node_id]
        node = canopen.RemoteNode(node_id, ObjectDictionary())
        node.sdo.RESPONSE_TIMEOUT = SDO_RESPONSE_TIMEOUT_S
        self.network.add_node(node)
        node.nmt.add_heartbeat_callback(lambda state, nid=node_id: self._on_heartbeat(nid, state))
        node.emcy.add_callback(lambda err, nid=node_id: self._on_emcy(nid, err))
        self.nodes[node_id] = node
        return node

    def on_fault(self, callback: FaultCallback) -> None:
        self._fault_callbacks.append(callback)

    def remove_fault_callback(self, callback: FaultCallback) -> None:
        if callback in self._fault_callbacks:
            self._fault_callbacks.remove(callback)

    def report(self, fault: BusFault) -> None:
        """Every callback hears of the fault; one that fails (a halt on a bus that has gone away)
        is logged, and neither stops the others nor the thread that reports (the watchdog)."""
        for cb in list(self._fault_callbacks):
            try:
                cb(fault)
            except Exception:  # the reporting thread (watchdog, SYNC) must live on
                log.exception("reporting %s of node %s failed", fault.kind, fault.node_id)

    # --- NMT -------------------------------------------------------------------------------------
    def nmt_broadcast(self, command: int) -> None:
        self.network.send_message(0, bytes([command, 0]))

    def nmt(self, node_id: int, command: int) -> None:
        self.network.send_message(0, bytes([command, node_id]))

    # --- heartbeat / EMCY consumers --------------------------------------------------------------
    def watch_heartbeat(self, node_ids: Iterable[int]) -> None:
        """Start checking the heartbeats of these nodes (after their 0x1017 has been written)."""
        now = time.monotonic()
        with self._lock:
            for nid in node_ids:
                self._heartbeat_seen.setdefault(nid, now)
                self._watched.add(nid)

    def unwatch_heartbeat(self) -> None:
        with self._lock:
            self._watched.clear()

    def heartbeat_state(self, node_id: int) -> int | None:
        return self._heartbeat_state.get(node_id)

    def boot_count(self, node_id: int) -> int:
        """How many boot-up messages this node has sent since the bus opened: a drive that boots again
        (reset, power loss) has lost what it knew (its homing, its configuration)."""
        return self._boots.get(node_id, 0)

    def _on_heartbeat(self, node_id: int, state: int) -> None:
        if state == NMT_STATE_BOOT_UP:
            self._boots[node_id] = self._boots.get(node_id, 0) + 1
        previous = self._heartbeat_state.get(node_id)
        self._heartbeat_seen[node_id] = time.monotonic()
        self._heartbeat_state[node_id] = state
        if node_id in self._watched and previous == NMT_STATE_OPERATIONAL and state != NMT_STATE_OPERATIONAL:
            self.report(BusFault(FaultKind.NMT, node_id, f"node {node_id} left OPERATIONAL (NMT state {state})"))

    def _on_emcy(self, node_id: int, err: EmcyError) -> None:
        if err.code == 0:
            return  # error reset / no error
        words = CAN_EMCY_WORDS.get(err.code) or err.get_desc()
        text = f"EMCY 0x{err.code:04X} from node {node_id}: {words}".rstrip(": ")
        self.report(BusFault(FaultKind.EMCY, node_id, text, err.code))

    def _watch(self) -> None:
        timeout = self.config.heartbeat_ms * self.config.heartbeat_timeout_factor / 1000.0
        poll = max(0.005, min(self.config.heartbeat_ms / 4000.0, self.lost_sync_timeout_s / 4))
        while not self._closing.wait(poll):
            now = time.monotonic()
            lost = []
            with self._lock:
                for nid in list(self._watched):
                    if now - self._heartbeat_seen.get(nid, now) > timeout:
                        lost.append(nid)
                        self._watched.discard(nid)
            for nid in lost:
                self.report(
                    BusFault(
                        FaultKind.HEARTBEAT,
                        nid,
                        f"no heartbeat from node {nid} for "
                        f"{now - self._heartbeat_seen[nid]:.3f} s (timeout {timeout:.3f} s)",
                    )
                )
            self._watch_wire(now)
            stalled = now - self.sync.last_progress > self.lost_sync_timeout_s
            if self.watch_sync and self.sync.running and not self._sync_reported and stalled:
                nodes = sorted({cob & 0x7F for cob in self.sync.behind()})
                self._sync_reported = True
                self.report(
                    BusFault(
                        FaultKind.LOST_SYNC,
                        nodes[0] if nodes else None,
                        f"SYNC {self.sync.count} not answered by node(s) {nodes} within "
                        f"{self.lost_sync_timeout_s:.3f} s",
                    )
                )

    def arm_sync_watch(self) -> None:
        self._sync_reported = False
        self.sync.last_progress = time.monotonic()
        self.watch_sync = True

    def _watch_wire(self, now: float) -> None:
        """Error frames (counted as they come, reported at most every ERROR_FRAME_REPORT_S) and the
        master's controller state (python-can's ``bus.state``), reported when it changes."""
        frames = self.errors.take(now, ERROR_FRAME_REPORT_S)
        if frames:
            self.report(
                BusFault(
                    FaultKind.BUS_WARNING,
                    None,
                    f"{frames} CAN error frame(s) in the last {ERROR_FRAME_REPORT_S:g} s ({self.errors.count} in all)",
                    frames,
                )
            )
        bus = self.network.bus
        if bus is None:
            return
        try:
            state = bus.state
        except (can.CanError, NotImplementedError, OSError):
            return
        if state == self.state:
            return
        previous, self.state = self.state, state
        if state == can.BusState.ERROR:
            self.report(
                BusFault(
                    FaultKind.BUS_OFF,
                    None,
                    "the master's CAN controller is bus-off: it can send nothing (no SYNC, no quick stop); "
                    "the drives stop on the master's heartbeat loss",
                )
            )
        elif state == can.BusState.PASSIVE:
            self.report(
                BusFault(FaultKind.BUS_WARNING, None, "the master's CAN controller is error passive (many errors)")
            )
        else:
            self.report(
                BusFault(
                    FaultKind.BUS_WARNING,
                    None,
                    f"the master's CAN controller is error active again (was {previous.name.lower()})",
                )
            )

    # --- the stop that does not need SYNC -------------------------------------------------------
    def quick_stop(
        self, node_ids: Iterable[int], reason: str, on_done: Callable[[QuickStop], None] | None = None
    ) -> QuickStop:
        """Quick stop these drives by SDO now, NMT stop for those that do not confirm (``axes.quick_stop``)."""
        return quick_stop_all(self, node_ids, reason, on_done)


class ErrorFrames(can.Listener):
    """Counts the error frames the interface delivers (``is_error_frame``)."""

    def __init__(self) -> None:
        self.count = 0
        self._reported = 0
        self._reported_at = 0.0

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            self.count += 1

    def take(self, now: float, every_s: float) -> int:
        """Error frames since the last report, when one is due (0: none, or not yet)."""
        new = self.count - self._reported
        if new <= 0 or now - self._reported_at < every_s:
            return 0
        self._reported, self._reported_at = self.count, now
        return new
