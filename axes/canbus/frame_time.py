"""What a CAN frame costs on the wire: its exact bit count (stuffing included) at a bit rate.

One place for the fact, used by the cell's bus budget (``axes/master/budget.py``), the simulated wire
(``axes/sim/wire``) and the wire benchmark. Classic CAN 2.0 data and remote frames (ISO 11898-1):

    SOF 1 | identifier 11 (base) or 11 + SRR 1 + IDE 1 + 18 (extended) | RTR 1 | IDE 1 + r0 1 (base)
    or r1 1 + r0 1 (extended) | DLC 4 | data 8 * n | CRC 15 | CRC delimiter 1 | ACK 2 | EOF 7 | IFS 3

From SOF to the end of the CRC sequence the transmitter inserts a complementary stuff bit after
five equal bits in a row (the stuff bit counts in the next run), so the count depends on the bits
themselves: it is computed, CRC included, not bounded. The 13 bits from the CRC delimiter on are
fixed form and never stuffed.
"""

from __future__ import annotations

import re
from functools import lru_cache

CRC15_POLY = 0x4599
FIXED_TAIL_BITS = 1 + 2 + 7 + 3  # CRC delimiter, ACK slot + delimiter, end of frame, intermission


def _crc15_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 7
        for _ in range(8):
            crc = ((crc << 1) ^ CRC15_POLY) if crc & 0x4000 else crc << 1
        table.append(crc & 0x7FFF)
    return tuple(table)


_CRC15_TABLE = _crc15_table()


def _crc15(value: int, width: int) -> int:
    """CRC-15/CAN of the ``width`` low bits of ``value``, most significant first. Zero bits in
    front leave a CRC from 0 at 0, so the bits go through the table a byte at a time."""
    crc = 0
    for byte in value.to_bytes((width + 7) // 8, "big"):
        crc = ((crc << 8) & 0x7FFF) ^ _CRC15_TABLE[((crc >> 7) ^ byte) & 0xFF]
    return crc


_LONG_RUNS = re.compile("0{4,}|1{4,}")  # maximal runs of four or more equal bits


def _stuffed_length(bits: str) -> int:
    """Length of ``bits`` ('0'/'1') once stuffed: a complementary bit after every run of five equal
    bits. That bit equals the next run's bits and counts in it, so a run of four right after a
    stuffed run is stuffed too; shorter runs never are."""
    stuffs = 0
    carry_to = -1  # where the run starts that the last stuff bit counts in
    for run in _LONG_RUNS.finditer(bits):
        length = run.end() - run.start() + (run.start() == carry_to)
        stuffs += length // 5
        carry_to = run.end() if length % 5 == 0 else -1
    return len(bits) + stuffs


@lru_cache(maxsize=65536)
def _frame_bits(can_id: int, extended: bool, remote: bool, dlc: int, data: bytes) -> int:
    if extended:
        base, ext = (can_id >> 18) & 0x7FF, can_id & 0x3FFFF
        # SOF 0, base, SRR 1, IDE 1, extension, RTR, r1 0, r0 0, DLC
        head, width = (((base << 2 | 0b11) << 18 | ext) << 3 | int(remote) << 2) << 4 | dlc, 1 + 11 + 2 + 18 + 3 + 4
    else:
        # SOF 0, identifier, RTR, IDE 0, r0 0, DLC
        head, width = ((can_id & 0x7FF) << 3 | int(remote) << 2) << 4 | dlc, 1 + 11 + 3 + 4
    payload = b"" if remote else data[:dlc]
    body = head << (8 * len(payload)) | int.from_bytes(payload, "big")
    width += 8 * len(payload)
    bits = f"{body:0{width}b}{_crc15(body, width):015b}"
    return _stuffed_length(bits) + FIXED_TAIL_BITS


def frame_bits(
    can_id: int, data: bytes = b"", *, extended: bool = False, remote: bool = False, dlc: int | None = None
) -> int:
    """Bits the frame occupies the bus for, interframe space included (exact stuffing)."""
    length = len(data) if dlc is None else dlc
    if not 0 <= length <= 8:
        raise ValueError(f"a classic CAN frame carries 0..8 bytes, got {length}")
    return _frame_bits(can_id, extended, remote, length, bytes(data))


def frame_seconds(bits: int, bitrate: int) -> float:
    """Time on a bus of ``bitrate`` bit/s."""
    return bits / float(bitrate)


def worst_frame_bits(payload_bytes: int, *, extended: bool = False) -> int:
    """The most bits a frame of this payload can take (every stuffable run stuffed): for budgets of
    frames whose content is not known in advance (SDO answers, EMCY)."""
    control = 1 + 11 + 1 + 1 + 1 + 4 if not extended else 1 + 11 + 1 + 1 + 18 + 1 + 1 + 1 + 4
    stuffable = control + 8 * payload_bytes + 15
    return stuffable + (stuffable - 1) // 4 + FIXED_TAIL_BITS
