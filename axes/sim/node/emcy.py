"""A simulated drive's error objects and its EMCY producer (CiA 301 0x1001, 0x1003, CiA 402 0x603F).

A fault sets the error code 0x603F, the error register 0x1001 and the pre-defined error field 0x1003
(newest first, up to four where the EDS has them) and sends its EMCY; a fault reset clears 0x1001 and
0x603F (the history stays) and sends EMCY 0x0000. Every EMCY the drive sends is kept (``sent``, for tests);
one is put on the bus only while the drive is on a network and not NMT STOPPED.
"""

from __future__ import annotations

import canopen

from pvtflow.axes.sim.node.dictionary import DriveDictionary

ERROR_CODE = 0x603F
EMCY_COMMUNICATION = 0x8100  # CiA 301: communication, generic
ERROR_REGISTER = 0x1001
ERROR_HISTORY = 0x1003
REGISTER_GENERIC = 0x01  # 0x1001 bits
REGISTER_COMMUNICATION = 0x10


class Emcy:
    """The error objects and the EMCY producer, a part of a ``SimulatedDrive`` (which gives it its node
    and dictionary and calls it under its own lock)."""

    def __init__(self, node: canopen.LocalNode, dictionary: DriveDictionary) -> None:
        self._node = node
        self._dictionary = dictionary
        self.sent: list[tuple[int, int, bytes]] = []  # (code, register, the 5 manufacturer bytes)

    def send(self, code: int, register: int | None = None, data: bytes = b"") -> None:
        if register is None:
            register = self._dictionary.read_or(ERROR_REGISTER, 0, 0) | (REGISTER_GENERIC if code else 0)
        payload = bytes(data[:5]).ljust(5, b"\0")
        self.sent.append((code, register, payload))
        if self._node.has_network() and self._node.nmt.state != "STOPPED":
            self._node.emcy.send(code, register, payload)

    def signal_fault(self, code: int, data: bytes, register: int) -> None:
        """0x603F, 0x1001, 0x1003 and the EMCY of a fault."""
        d = self._dictionary
        if d.has(ERROR_CODE):
            d.store(ERROR_CODE, 0, code)
        d.store(ERROR_REGISTER, 0, register)
        if d.has(ERROR_HISTORY, 1):
            n = min(d.read(ERROR_HISTORY, 0) + 1, 4) if d.has(ERROR_HISTORY, 4) else 1
            for k in range(n, 1, -1):
                d.store(ERROR_HISTORY, k, d.read(ERROR_HISTORY, k - 1))
            d.store(ERROR_HISTORY, 1, code)
            d.store(ERROR_HISTORY, 0, n)
        self.send(code, register, data)

    def clear_errors(self) -> None:
        """A fault reset: 0x1001 and 0x603F back to 0 (the history 0x1003 stays)."""
        self._dictionary.store(ERROR_REGISTER, 0, 0)
        if self._dictionary.has(ERROR_CODE):
            self._dictionary.store(ERROR_CODE, 0, 0)
