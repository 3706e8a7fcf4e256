"""What a CAN frame costs on the wire: its exact bit count (stuffing included) at a bit rate.

One place for the fact, used by the cell's bus budget (``axes/budget.py``), the simulated wire
(``axes/sim/wire``) and the wire benchmark. Classic CAN 2.0 data and remote frames (ISO 11898-1):

    SOF 1 | identifier 11 (base) or 11 + SRR 1 + IDE 1 + 18 (extended) | RTR 1 | IDE 1 + r0 1 (base)
    or r1 1 + r0 1 (extended) | DLC 4 | data 8 * n | CRC 15 | CRC delimiter 1 | ACK 2 | EOF 7 | IFS 3

From SOF to the end of the CRC sequence the transmitter inserts a complementary stuff bit after
five equal bits in a row (the stuff bit counts in the next run), so the count depends on the bits
themselves: it is computed, CRC included, not bounded. The 13 bits from the CRC delimiter on are
fixed form and never stuffed.
"""

from __future__ import annotations

from functools import lru_cache

CRC15_POLY = 0x4599
FIXED_TAIL_BITS = 1 + 2 + 7 + 3  # CRC delimiter, ACK slot + delimiter, end of frame, intermission


def _bits(value: int, width: int) -> list[int]:
    return [(value >> (width - 1 - i)) & 1 for i in range(width)]


def _crc15(bits: list[int]) -> int:
    crc = 0
    for bit in bits:
        top = ((crc >> 14) & 1) ^ bit
        crc = (crc << 1) & 0x7FFF
        if top:
            crc ^= CRC15_POLY
    return crc


def _stuffed_length(bits: list[int]) -> int:
    """Length of ``bits`` once stuffed: a complementary bit after every run of five equal bits."""
    out = 0
    run_bit = -1
    run = 0
    for bit in bits:
        out += 1
        if bit == run_bit:
            run += 1
        else:
            run_bit, run = bit, 1
        if run == 5:
            out += 1  # the stuff bit, the complement, starts the next run
            run_bit, run = 1 - bit, 1
    return out


@lru_cache(maxsize=65536)
def _frame_bits(can_id: int, extended: bool, remote: bool, dlc: int, data: bytes) -> int:
    if extended:
        base, ext = (can_id >> 18) & 0x7FF, can_id & 0x3FFFF
        head = [0, *_bits(base, 11), 1, 1, *_bits(ext, 18), int(remote), 0, 0, *_bits(dlc, 4)]
    else:
        head = [0, *_bits(can_id & 0x7FF, 11), int(remote), 0, 0, *_bits(dlc, 4)]
    payload = [] if remote else [b for byte in data[:dlc] for b in _bits(byte, 8)]
    body = head + payload
    body += _bits(_crc15(body), 15)
    return _stuffed_length(body) + FIXED_TAIL_BITS


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
