"""The master's handle on one drive: what a failed SDO transfer becomes."""

from __future__ import annotations

import can
import pytest

from pvtflow.axes.master.link import DriveError
from pvtflow.service.config import CONFIG_DIR, load_cell_config


def test_a_request_the_bus_refuses_is_a_drive_error_naming_the_object(make_rig, monkeypatch) -> None:
    """A full transmit queue (python-can's CanOperationError, ENOBUFS on socketcan) during an SDO read reaches the
    caller as DriveError, which the service answers as bus_error, never as a traceback."""
    rig = make_rig(load_cell_config(CONFIG_DIR / "cells" / "gantry3.yaml"))
    link = rig.group.links[0]

    def refuse(*_args: object, **_kwargs: object) -> None:
        raise can.CanOperationError("Failed to transmit: No buffer space available", 105)

    monkeypatch.setattr(link.node.network, "send_message", refuse)
    with pytest.raises(DriveError, match=r"0x6041:00 failed: .*No buffer space") as failed:
        link.read_statusword()
    assert failed.value.node_id == link.node_id
