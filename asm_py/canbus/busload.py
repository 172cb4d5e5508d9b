"""Worst-case CAN bus load from frame sizes and rates, with worst-case bit stuffing.

Classic frames (Davis, Burns, Bril, Lukkien, "Controller Area Network (CAN) schedulability analysis", 2007): of a
frame with n data bytes, g + 8n bits are subject to stuffing (g = 34 for 11-bit, 54 for 29-bit identifiers), at worst
one stuff bit per 4 after the first, plus 13 bits of CRC delimiter, ACK, end of frame and interframe space:

    bits(n) = g + 8n + 13 + floor((g + 8n - 1) / 4)        e.g. 29-bit, 8 bytes: 160 bits

CAN FD frames (ISO 11898-1:2015): the arbitration phase (SOF to BRS) at the nominal bit rate, stuffed as above; the
data phase (ESI, DLC, data, stuff count, CRC-17/21 with its fixed stuff bits) at the data bit rate, dynamic stuffing
at worst 1 in 4 up to the CRC; the CRC delimiter, ACK, EOF and interframe space at the nominal rate again.

CLI: ``python -m asm_py.canbus.busload --bitrate 1000000 8x5000 4x100`` (frames of 8 data bytes 5000 times a
second, and so on); ``--fd --data-bitrate 5000000`` for CAN FD, ``--standard`` for 11-bit identifiers.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Iterable

from ..cli import bitrate, bounded
from .fragments import fd_size


def classic_frame_bits(data_bytes: int, *, extended: bool = True) -> int:
    """Worst-case length in bits of a classic CAN frame, stuffing and interframe space included."""
    if not 0 <= data_bytes <= 8:
        raise ValueError(f"a classic CAN frame carries 0..8 data bytes, not {data_bytes}")
    g = 54 if extended else 34
    stuffed = g + 8 * data_bytes
    return stuffed + 13 + (stuffed - 1) // 4


def fd_frame_time(data_bytes: int, bitrate: float, data_bitrate: float, *, extended: bool = True) -> float:
    """Worst-case duration in seconds of a CAN FD frame (bit rate switch on)."""
    size = fd_size(data_bytes)
    arbitration = 1 + (32 if extended else 12) + 3  # SOF, identifier (+SRR, IDE), RRS/r1, FDF, res
    arbitration += (arbitration - 1) // 4  # stuffing
    arbitration += 1  # BRS (sampled at the nominal rate)
    crc_bits = 17 if size <= 16 else 21
    dynamic = 1 + 4 + 8 * size  # ESI, DLC, data
    dynamic += (dynamic - 1) // 4
    fixed = 4 + crc_bits  # stuff count (3 + parity), CRC
    fixed += math.ceil(fixed / 4)  # a fixed stuff bit every 4 bits
    tail = 1 + 2 + 7 + 3  # CRC delimiter, ACK slot + delimiter, EOF, IFS
    return (arbitration + tail) / bitrate + (dynamic + fixed) / data_bitrate


def bus_load(
    frames: Iterable[tuple[int, float]],
    bitrate: float,
    *,
    extended: bool = True,
    fd: bool = False,
    data_bitrate: float | None = None,
) -> float:
    """The fraction of bus time used by ``frames``: (data bytes per frame, frames per second) pairs."""
    if bitrate <= 0:
        raise ValueError("bitrate must be positive")
    busy = 0.0
    for data_bytes, rate in frames:
        if fd:
            busy += rate * fd_frame_time(data_bytes, bitrate, data_bitrate or bitrate, extended=extended)
        else:
            busy += rate * classic_frame_bits(data_bytes, extended=extended) / bitrate
    return busy


def _frames(spec: str) -> tuple[int, float]:
    """``BYTESxRATE``: data bytes 0..64 and a rate >= 0 frames per second, finite."""
    size, sep, rate = spec.partition("x")
    if not sep:
        raise argparse.ArgumentTypeError(f"{spec!r} is not BYTESxRATE, e.g. 8x5000")
    return bounded(int, 0, 64, what="data bytes")(size), bounded(float, 0, 1e9, what="frames per second")(rate)


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="asm-busload", description=(__doc__ or "").splitlines()[0])
    cli.add_argument("frames", nargs="+", type=_frames, metavar="BYTESxRATE", help="data bytes x frames per second")
    cli.add_argument("--bitrate", type=bitrate, default=1_000_000, help="nominal bit rate (default 1 Mbit/s)")
    cli.add_argument("--fd", action="store_true", help="CAN FD frames with bit rate switch")
    cli.add_argument("--data-bitrate", type=bitrate, help="CAN FD data phase bit rate (default: the nominal rate)")
    cli.add_argument("--standard", action="store_true", help="11-bit identifiers (default 29-bit)")
    args = cli.parse_args(argv)
    try:
        load = bus_load(args.frames, args.bitrate, extended=not args.standard, fd=args.fd,
                        data_bitrate=args.data_bitrate)  # fmt: skip
    except ValueError as exc:
        cli.error(str(exc))
    total = sum(rate for _, rate in args.frames)
    print(f"bus load {load * 100:.1f}% at {args.bitrate:,.0f} bit/s ({total:,.0f} frames/s, worst-case stuffing)")
    return 0 if load <= 1.0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
