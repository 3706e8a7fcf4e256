"""The two clocks a cell's bus runs on, one name each: the master, the simulated wire and drives, the
service and its commands all say ``Clock.LOCKSTEP`` or ``Clock.WALL``.

``LOCKSTEP``: SYNC waits for the drives' answers and bus time advances one SYNC period per SYNC
(deterministic tests, faster than real time). ``WALL``: SYNC runs on the host's clock and every drive on
its own (the hardware's way). The values are the simulated wire's ``clock`` option (``can.Bus(...,
clock="wall")``); the user-facing spellings (``--wall-clock``, a JSON ``real_time``) map onto these.
"""

from __future__ import annotations

from enum import StrEnum


class Clock(StrEnum):
    LOCKSTEP = "lockstep"
    WALL = "wall"

    @classmethod
    def of(cls, lockstep: bool) -> Clock:
        """The clock of a bus run in lockstep or not (the master's ``lockstep`` flag)."""
        return cls.LOCKSTEP if lockstep else cls.WALL

    @property
    def lockstep(self) -> bool:
        return self is Clock.LOCKSTEP
