"""The canopen Network the master sends through: every frame recorded, a refused frame tried again.

A bus does not hear its own frames, so ``LoggingNetwork`` hands each frame it sends to the
``FrameLog`` too, which counts every frame and, with a log file, writes it through
``can.Logger`` (the ``--can-log`` of the commands). A frame the interface refuses (a full transmit
queue, ENOBUFS) is tried again for ``BusConfig.tx_retry_ms``, or longer for bulk frames nothing
waits on (``LoggingNetwork.patient``); past that it raises, and the SYNC thread reports
``FaultKind.TX_FAILED``.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import canopen

TX_RETRY_PAUSE_S = 0.0002  # between two tries of a frame the interface refused


def sent_together(bus: can.BusABC | None) -> contextlib.AbstractContextManager[None]:
    """Frames the calling thread sends on ``bus`` inside it go to the interface together where it can take a
    run of frames in one call (simwire's loopback client: ``SimWireBus.coalesced``, one write: a process held
    between two writes would leave a frame stamped but not yet sent); elsewhere (socketcan, virtual, pcan: one
    frame per call) each goes as it is sent. Each is refused on its own."""
    coalesced = getattr(bus, "coalesced", None)
    return coalesced() if coalesced is not None else contextlib.nullcontext()


class FrameLog(can.Listener):
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


class LoggingNetwork(canopen.Network):
    """A canopen Network whose own frames go to the recorder too (a bus does not hear itself)."""

    def __init__(self, bus: can.BusABC | None = None, recorder: FrameLog | None = None) -> None:
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
        transmit queue only delays by the wire time of what is ahead of them. ``seconds`` 0: one try
        (the caller tries again itself, between other work: ``axes.master.bus.quick_stop``)."""
        previous = getattr(self._patience, "seconds", None)
        self._patience.seconds = seconds
        try:
            yield
        finally:
            self._patience.seconds = previous

    def together(self) -> contextlib.AbstractContextManager[None]:
        """Frames this thread sends inside it go to the interface together (``sent_together``)."""
        return sent_together(self.bus)

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
                patience = getattr(self._patience, "seconds", None)
                bound = self.tx_retry_s if patience is None else patience
                if deadline is None:
                    deadline = now + bound
                self.tx_retries += 1
                if now >= deadline:
                    raise can.CanOperationError(
                        f"frame 0x{can_id:03X} not sent within {bound * 1000:.1f} ms: {exc}"
                    ) from exc
                time.sleep(TX_RETRY_PAUSE_S)
                wait = max(deadline - time.monotonic(), 0.0)
        if self.recorder is not None:
            self.recorder.on_message_sent(msg)
