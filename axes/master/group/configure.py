"""Configuring the cell's drives for a run, and checking a program against the cell: a part of ``AxisGroup``.

Configuration checks every drive against the cell (``axes.master.commission``), then writes its profile's
SDO sequence in PRE-OPERATIONAL, and arms the consumers; a drive that booted since (a reset, a power
loss) has its EDS defaults again and is configured again before the next start.
"""

from __future__ import annotations

from collections.abc import Sequence

from pvtflow.axes.drive.objects import NmtCommand
from pvtflow.axes.drive.program import PvtProgram, program_mismatch
from pvtflow.axes.master.bus.cell_bus import CellBus
from pvtflow.axes.master.commission import refuse_on_facts
from pvtflow.axes.master.feed_check import BufferedAxis, feed_shortfall
from pvtflow.axes.master.group.feeder import RecordAllowance
from pvtflow.axes.master.group.readiness import Readiness
from pvtflow.axes.master.link import AxisLink
from pvtflow.axes.master.profiles.base import Profile

# frames sent while nothing moves (configuration, recovery) wait this long at most for room in a full
# transmit queue: its frames take their wire time, a few ms, and a bus that takes none is broken (as the
# preload's, axes.master.group.start)
SETUP_PATIENCE_S = 0.1


class Configured:
    """Whether the group's drives hold its configuration, and every drive's boot count when it was
    written: a drive that booted since has its EDS defaults again. The one writer of both."""

    def __init__(self) -> None:
        self.done = False
        self.boots: dict[int, int] = {}

    def writing(self, boots: dict[int, int]) -> None:
        """Configuration starts on drives that have booted this often (``rebooted`` compares)."""
        self.boots = boots

    def written(self) -> None:
        self.done = True

    def forget(self) -> None:
        """The next start configures again (a drive may come back reset, or sits in NMT STOPPED)."""
        self.done = False


class CellSetup:
    """Configures a group's drives and checks its programs against the cell (a part of ``AxisGroup``)."""

    def __init__(
        self,
        bus: CellBus,
        links: Sequence[AxisLink],
        profiles: Sequence[Profile],
        readiness: Readiness,
        allowance: RecordAllowance,
    ) -> None:
        self.bus = bus
        self.links = links
        self.profiles = profiles
        self.readiness = readiness
        self.allowance = allowance
        self.configuration = Configured()

    @property
    def configured(self) -> bool:
        """Configured since every drive last booted, as far as the group knows (``rebooted`` checks)."""
        return self.configuration.done

    def configure(self) -> None:
        """Every drive: what it is checked against the cell (axes/master/commission.py: a drive that is not
        what the cell says is refused, DriveError, before anything is written), then PRE-OPERATIONAL,
        its profile's SDO sequence, then OPERATIONAL and consumers."""
        with self.bus.network.patient(SETUP_PATIENCE_S):
            self._configure()

    def _configure(self) -> None:
        refuse_on_facts(self.links, self.profiles)
        for link in self.links:  # addressed, not broadcast: other nodes on the bus are not ours
            self.bus.nmt(link.node_id, NmtCommand.PRE_OPERATIONAL)
        self.configuration.writing({link.node_id: self.bus.watch.boot_count(link.node_id) for link in self.links})
        for link, profile in zip(self.links, self.profiles, strict=True):
            profile.configure()
            profile.write_homing()
            link.subscribe_tpdos(profile.tpdos)
        self.expect_answers()
        for link in self.links:
            self.bus.nmt(link.node_id, NmtCommand.START)
        self.bus.watch.watch_heartbeat(link.node_id for link in self.links)
        self.readiness.forget()
        self.configuration.written()

    def expect_answers(self) -> None:
        """SYNC waits for (lockstep) and watches every drive's answer on its profile's TPDO."""
        self.bus.sync.expect({p.sync_answer_cob_id: p.sync_answer_every for p in self.profiles})

    def configure_if_needed(self) -> None:
        """Configure unless configured since every drive last booted (a rebooted drive has its EDS
        defaults again: no PDOs, no mode, no homing settings)."""
        if not self.configured or self.rebooted():
            self.configure()

    def rebooted(self) -> bool:
        """A drive has booted since the group configured it."""
        boots = self.configuration.boots
        return any(self.bus.watch.boot_count(lk.node_id) != boots.get(lk.node_id) for lk in self.links)

    def check_program(self, program: PvtProgram) -> str | None:
        """Why this program cannot run on this cell (None: it can)."""
        problems = program_mismatch(program, [link.config for link in self.links], "this cell")
        if problems:
            return "; ".join(problems[:3])
        by_node = {a.node_id: a for a in program.axes}
        buffered = [
            BufferedAxis(link.joint, by_node[link.node_id].records, link.config.buffer)
            for link, profile in zip(self.links, self.profiles, strict=True)
            if not profile.fixed_period and link.node_id in by_node
        ]
        return feed_shortfall(buffered, self.allowance.per_sync, self.bus.config.sync_period_ms)
