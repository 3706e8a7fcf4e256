"""The bit count of a frame on the wire: checked against the stuffed bit stream built bit by bit."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from pvtflow.axes.canbus.frame_time import frame_bits, frame_seconds, worst_frame_bits


def _crc15(bits: list[int]) -> int:
    # the CRC as ISO 11898-1 writes it: shift register, polynomial x^15+x^14+x^10+x^8+x^7+x^4+x^3+1
    reg = [0] * 15
    for bit in bits:
        nxt = bit ^ reg[0]
        reg = [*reg[1:], 0]
        if nxt:
            for tap in (0, 4, 6, 7, 10, 11, 14):  # 0x4599 read from the top bit down
                reg[tap] ^= 1
    return int("".join(map(str, reg)), 2)


def _stream(can_id: int, data: bytes) -> list[int]:
    """The bits of a base data frame from SOF to the end of the CRC, stuffed."""
    raw = [0] + [int(b) for b in f"{can_id:011b}"] + [0, 0, 0] + [int(b) for b in f"{len(data):04b}"]
    raw += [int(b) for byte in data for b in f"{byte:08b}"]
    raw += [int(b) for b in f"{_crc15(raw):015b}"]
    out: list[int] = []
    for bit in raw:
        out.append(bit)
        if len(out) >= 5 and len(set(out[-5:])) == 1:
            out.append(1 - bit)
    return out


@given(st.integers(0, 0x7FF), st.binary(min_size=0, max_size=8))
def test_frame_bits_is_the_stuffed_stream_plus_the_fixed_tail(can_id: int, data: bytes) -> None:
    stream = _stream(can_id, data)
    assert frame_bits(can_id, data) == len(stream) + 13
    runs = "".join(map(str, stream))
    assert "000000" not in runs and "111111" not in runs


@given(st.integers(0, 0x7FF), st.binary(min_size=0, max_size=8))
def test_no_frame_exceeds_the_worst_case(can_id: int, data: bytes) -> None:
    assert 47 + 8 * len(data) <= frame_bits(can_id, data) <= worst_frame_bits(len(data))


def test_the_textbook_extremes() -> None:
    assert worst_frame_bits(8) == 135  # base frame, 8 bytes, every stuff bit, 3 bits of intermission
    assert worst_frame_bits(8, extended=True) == 160
    assert frame_seconds(frame_bits(0x80), 1_000_000) == frame_bits(0x80) * 1e-6
