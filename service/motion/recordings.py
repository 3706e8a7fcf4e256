"""A run's recording: its MCAP file (``record_dir``/ID.mcap) and the live channels, attached to the bus."""

from __future__ import annotations

import logging
from pathlib import Path

from pvtflow.service.config import CellConfig
from pvtflow.service.live import LiveServer
from pvtflow.service.motion.drives import CellDrives
from pvtflow.service.recording import Recorder

log = logging.getLogger("pvtflow.motion")


class RunRecordings:
    """Where the cell's motions and homings are recorded: a folder, the live server, or neither."""

    def __init__(self, cell: CellConfig, drives: CellDrives, record_dir: Path | None, live: LiveServer | None) -> None:
        self.cell = cell
        self.drives = drives
        self.record_dir = record_dir  # one MCAP file per motion
        self.live = live  # every motion's channels served live too (service/live.py)

    def open(self, run_id: str, kind: str) -> Recorder | None:
        """The run's recording, attached to the bus; None without a folder or a live server, or when the
        file cannot be written (logged: the run does not depend on it)."""
        bus = self.drives.bus
        if (self.record_dir is None and self.live is None) or bus is None:
            return None
        path = None
        try:
            if self.record_dir is not None:
                self.record_dir.mkdir(parents=True, exist_ok=True)
                path = self.record_dir / f"{run_id}.mcap"
            return Recorder(path, self.cell, kind=kind, live=self.live).attach(bus, self.drives.group)
        except OSError as exc:
            log.warning("no recording of %s: %s", run_id, exc)
            return None
