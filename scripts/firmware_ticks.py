"""Instructions per tick of the firmware bench image, from a qemu ``-singlestep -d exec`` trace (scripts/build_firmware).

    python3 scripts/firmware_ticks.py TRACE.log BENCH_MARK_ADDRESS
"""

from __future__ import annotations

import sys

CPU_HZ = 84e6  # the STM32F401's clock in the port
PERIOD_S = 1e-3  # a 1 kHz tick
N_TICKS = 11
LEGEND = "1 HELLO+CONFIG, 2-4 eight COMMANDs, 5-10 silence (faults latch), 11 CLEAR_FAULT; 100 bytes received a tick"


def tick_instructions(trace: str, mark: str) -> list[int]:
    """Instructions executed between consecutive pairs of bench_mark entries (its own ``bx lr`` not counted)."""
    mark = mark.lstrip("0").lower()
    with open(trace) as f:
        pcs = [line.split("/")[1].lstrip("0").lower() for line in f if line.startswith("Trace")]
    at = [i for i, pc in enumerate(pcs) if pc == mark]
    return [b - a - 1 for a, b in zip(at[0::2], at[1::2], strict=True)]


def main(argv: list[str]) -> int:
    ticks = tick_instructions(argv[1], argv[2])
    if len(ticks) != N_TICKS:
        print(f"build_firmware: expected {N_TICKS} measured ticks in the qemu trace, found {len(ticks)}", file=sys.stderr)
        return 1
    print(f"firmware: instructions per tick (qemu, bench.c: {LEGEND}): {' '.join(map(str, ticks))}")
    worst = max(ticks)
    lo, hi = worst / CPU_HZ, 2 * worst / CPU_HZ
    print(f"firmware: worst tick {worst} instructions = {worst}-{2 * worst} cycles at 1-2 cycles/instruction, "
          f"{lo * 1e6:.0f}-{hi * 1e6:.0f} µs at 84 MHz = {lo / PERIOD_S:.0%}-{hi / PERIOD_S:.0%} of a 1 kHz period "
          "(on the board, tick_cycles_max holds the measured worst)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
