"""The drive profiles pvtflow knows, each with one description that every layer asks.

A cell file names an axis's profile (``profile: epos2_pvt``) and a program file carries the same
name; the readers turn it into a ``DriveProfile`` and nothing else spells it. What depends on the
profile alone is described here: fixed period or buffered, the buffer, the interpolation submodes
and the reconstruction the drive makes for a period and a submode, the shortest SYNC period pvtflow
holds for it, the PDOs the master maps, its homing methods and the identities of its drives. How it
behaves on the bus (configuration, feeding) is its module in axes/profiles, its simulation in axes/sim.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum

from pvtflow.axes.drive import objects as od
from pvtflow.axes.drive.interpolation import Interpolation
from pvtflow.axes.drive.objects import DriveIdentity, PdoLayout

PERIOD_RANGE_MS = (1, 255)  # a record's time is a u8 of ms


@dataclass(frozen=True)
class ProfileSpec:
    """What one profile is, independent of any cell."""

    fixed_period: bool  # one setpoint per SYNC, sent right after the SYNC before it; else buffered records
    buffer_records: int  # records the drive holds ahead (0: none, it takes each setpoint as it comes)
    interpolation: Interpolation  # the reconstruction without submodes (or below ``submodes_from_us``)
    rpdos: tuple[PdoLayout, ...]
    tpdos: tuple[PdoLayout, ...]
    sync_tpdo: int  # the synchronous TPDO that answers every SYNC
    product_code: int  # the simulated drive's 0x1018:02 (vendor ``objects.SIMULATED_VENDOR_ID``)
    simulated_name: str
    homing_methods: frozenset[int] = frozenset()  # 0x6098 values it homes with (none: no mode 6)
    # 0x60C0 value -> the reconstruction it makes, from a cycle of ``submodes_from_us`` on
    submodes: Mapping[int, Interpolation] = field(default_factory=dict)
    default_submode: int | None = None
    submodes_from_us: int = 0
    # The shortest SYNC period pvtflow holds for a fixed-period drive: its setpoints go out from the
    # thread that sends SYNC, one per period, and a CPython master holds 1 ms on the wall clock
    # (bench/realtime.py) but not less. The seeds ask no less: the linear IP drive's 0x60C2 counts
    # whole ms (1 ms recommended), the bufferless drive takes 1.0-100.0 ms, the Parker's direct loop
    # runs at any cycle below 2.5 ms.
    shortest_period_ms: float | None = None
    period_range_ms: tuple[int, int] = PERIOD_RANGE_MS  # the setpoint periods the drive takes
    vendor_identities: tuple[DriveIdentity, ...] = ()  # real drives of this profile pvtflow knows


class ProfileError(ValueError):
    """An axis's setting its profile does not take; ``field`` is the cell file's name of it."""

    def __init__(self, field: str, problem: str) -> None:
        self.field = field
        self.problem = problem
        super().__init__(f"{field}: {problem}")


class DriveProfile(StrEnum):
    """A drive profile by its cell-file name; ``spec`` is its description."""

    EPOS2_PVT = "epos2_pvt"  # maxon EPOS2 buffered PVT (interpolated position mode, 64-record FIFO)
    CIA402_IP_LINEAR = "cia402_ip_linear"  # CiA 402 interpolated position, linear, one setpoint per SYNC
    SYNC_SETPOINT = "sync_setpoint"  # a bufferless servodrive taking one setpoint per SYNC
    PARKER_SLVDN = "parker_slvdn"  # Parker SLVDN operative mode 202, submodes 0 / -1 / -2

    @classmethod
    def parse(cls, name: object) -> DriveProfile:
        """The profile named ``name`` (ValueError naming the known ones)."""
        try:
            return cls(name)
        except ValueError:
            raise ValueError(f"unknown drive profile {name!r} (one of {', '.join(cls)})") from None

    @property
    def spec(self) -> ProfileSpec:
        return _SPECS[self]

    @property
    def fixed_period(self) -> bool:
        return self.spec.fixed_period

    @property
    def buffered(self) -> bool:
        return self.spec.buffer_records > 0

    @property
    def has_submodes(self) -> bool:
        return bool(self.spec.submodes)

    def submode(self, submode: int | None) -> int | None:
        """The 0x60C0 value in force: ``submode``, or the profile's default where it is None (None:
        the profile has no submodes)."""
        if not self.spec.submodes:
            return None
        return self.spec.default_submode if submode is None else submode

    def reconstruction(self, period_ms: float | None, submode: int | None = None) -> Interpolation:
        """The reconstruction the drive makes of its records at a setpoint period of ``period_ms``
        in ``submode``: the Parker interpolates its submodes only from a 2.5 ms cycle on; below, its
        position loop takes each setpoint as it comes, which on the program's timeline is linear."""
        spec = self.spec
        if spec.submodes and (period_ms or 0) * 1000.0 >= spec.submodes_from_us:
            return spec.submodes[self.submode(submode)]  # type: ignore[index]
        return spec.interpolation

    def carries_velocity(self, submode: int | None = None) -> bool:
        """The records' velocities go to the drive (EPOS2 records, Parker -1 setpoints); else they are 0."""
        if self.spec.submodes:
            return self.spec.submodes[self.submode(submode)] is Interpolation.CUBIC_PV  # type: ignore[index]
        return self.spec.interpolation is Interpolation.PVT

    def settings(
        self, sync_period_ms: float, period_ms: int | None, submode: int | None
    ) -> tuple[int | None, int | None]:
        """The axis's setpoint period and 0x60C0 submode on a bus of ``sync_period_ms``, from the cell
        file's (None: not given): a fixed-period drive takes one setpoint per SYNC, so its period is the
        SYNC period, no shorter than the profile's shortest; a drive with submodes gets its default.
        ProfileError names the field a drive of this profile cannot take."""
        spec = self.spec
        if spec.fixed_period:
            shortest = spec.shortest_period_ms or 0.0
            if sync_period_ms < shortest:
                raise ProfileError(
                    "profile",
                    f"{self} takes one setpoint per SYNC, sent right after the SYNC before it: the shortest SYNC "
                    f"period pvtflow holds for it is {shortest:g} ms, bus.sync_period_ms is {sync_period_ms:g}",
                )
            if period_ms is None:
                if sync_period_ms != round(sync_period_ms):
                    raise ProfileError(
                        "period_ms", f"missing, and the SYNC period {sync_period_ms} ms is not a whole number of ms"
                    )
                period_ms = round(sync_period_ms)
            lo, hi = spec.period_range_ms
            if not lo <= period_ms <= hi:
                raise ProfileError("period_ms", f"a {self} drive takes {lo} to {hi} ms per setpoint, got {period_ms}")
            if period_ms != sync_period_ms:
                raise ProfileError(
                    "period_ms",
                    f"{self} gets one setpoint per SYNC (the Parker's cycle 0x1006 is the SYNC period): "
                    f"must equal bus.sync_period_ms ({sync_period_ms:g}), got {period_ms}",
                )
        elif period_ms is not None:
            fixed = ", ".join(p for p in DriveProfile if p.fixed_period)
            raise ProfileError("period_ms", f"only fixed-period profiles ({fixed}) have one")
        if submode is not None and submode not in spec.submodes:
            if not spec.submodes:
                raise ProfileError("interpolation_submode", f"the {self} profile has no interpolation submodes")
            have = ", ".join(str(m) for m in spec.submodes)
            raise ProfileError("interpolation_submode", f"{submode} is not one of {self}'s ({have})")
        return period_ms, self.submode(submode)

    @property
    def identities(self) -> tuple[DriveIdentity, ...]:
        """The drives this profile may find (the commissioning check, axes/master/commission.py): its
        simulated drive and the real ones pvtflow knows."""
        spec = self.spec
        return (DriveIdentity(od.SIMULATED_VENDOR_ID, spec.product_code, spec.simulated_name), *spec.vendor_identities)


_FIXED_PERIOD = {
    "fixed_period": True,
    "buffer_records": 0,
    "interpolation": Interpolation.LINEAR,
    "shortest_period_ms": 1.0,
}

_SPECS: dict[DriveProfile, ProfileSpec] = {
    DriveProfile.EPOS2_PVT: ProfileSpec(
        fixed_period=False,
        buffer_records=od.EPOS2_BUFFER_SIZE,
        interpolation=Interpolation.PVT,
        rpdos=od.EPOS2_RPDOS,
        tpdos=od.EPOS2_TPDOS,
        sync_tpdo=2,
        product_code=1,
        simulated_name="pvtflow simulated EPOS2",
        homing_methods=od.EPOS2_HOMING_METHODS,
        vendor_identities=(od.MAXON_EPOS2_70_10,),
    ),
    DriveProfile.CIA402_IP_LINEAR: ProfileSpec(
        **_FIXED_PERIOD,  # type: ignore[arg-type]
        rpdos=od.SETPOINT_RPDOS,
        tpdos=od.SETPOINT_TPDOS,
        sync_tpdo=1,
        product_code=2,
        simulated_name="pvtflow simulated CiA 402 linear IP drive",
    ),
    DriveProfile.SYNC_SETPOINT: ProfileSpec(
        **_FIXED_PERIOD,  # type: ignore[arg-type]
        rpdos=od.SETPOINT_RPDOS,
        tpdos=od.SETPOINT_TPDOS,
        sync_tpdo=1,
        product_code=3,
        simulated_name="pvtflow simulated bufferless IP servodrive",
        homing_methods=od.CIA402_HOMING_METHODS,  # mode 6 (the seed's 0x60E3: "see the servodrive manual")
        period_range_ms=(1, 100),  # the seed's 1.0-100.0 ms
    ),
    DriveProfile.PARKER_SLVDN: ProfileSpec(
        **_FIXED_PERIOD,  # type: ignore[arg-type]
        rpdos=od.PARKER_RPDOS,
        tpdos=od.PARKER_TPDOS,
        sync_tpdo=1,
        product_code=4,
        simulated_name="pvtflow simulated Parker SLVDN",
        submodes={0: Interpolation.LINEAR, -1: Interpolation.CUBIC_PV, -2: Interpolation.CUBIC_P},
        default_submode=-1,
        submodes_from_us=od.PARKER_CUBIC_THRESHOLD_US,
    ),
}
