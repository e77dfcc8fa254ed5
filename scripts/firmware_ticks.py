"""Instructions and cycles per tick of the firmware bench image, from a qemu ``-singlestep -d exec`` trace.

    python3 scripts/firmware_ticks.py TRACE.log BENCH.elf        (scripts/build_firmware runs it)

qemu logs every instruction the bench (firmware/stm32f4/bench.c) executes; the instructions between two calls of
``bench_mark`` are one tick. Cycles come from a per-instruction worst-case model of the Cortex-M4 (ARM DDI 0439B,
"Processor instruction timings") applied to that executed sequence: loads and stores 2 (3 for the doubleword
forms), LDM/STM/PUSH/POP 1 + registers, divides 12, a taken branch 1 + 3 for the pipeline refill + 2 flash wait
states as if the ART cache always missed (84 MHz, 2 wait states), a POP or load into pc the same; everything else
1. Interrupt entry and exit (12 + 12) are added to each tick. Pipelining and cache hits only make it faster.
"""

from __future__ import annotations

import re
import subprocess
import sys

CPU_HZ = 84e6  # the STM32F401's clock in the port
PERIOD_S = 1e-3  # a 1 kHz tick
EXCEPTION_CYCLES = 24  # entry + exit of the tick interrupt
REFILL, WAIT_STATES = 3, 2
N_TICKS = 11
LEGEND = "1 HELLO+CONFIG, 2-4 six COMMANDs, 5-10 silence (faults latch), 11 CLEAR_FAULT; 100 bytes received a tick"
LINE = re.compile(r"^\s*([0-9a-f]+):\t((?:[0-9a-f]{4} ?)+)\s*\t(\S+)\s*(.*)$")
SYMBOL = re.compile(r"^([0-9a-f]+) <bench_mark>:$")
BRANCHES = re.compile(r"^(b|bl|blx|bx|cbz|cbnz|tbb|tbh)(eq|ne|cs|hs|cc|lo|mi|pl|vs|vc|hi|ls|ge|lt|gt|le|al)?(\.[nw])?$")


def disassemble(elf: str) -> tuple[dict[int, tuple[int, str, str]], int]:
    """{address: (size, mnemonic, operands)} of the image, and bench_mark's address."""
    text = subprocess.run(["arm-none-eabi-objdump", "-d", elf], capture_output=True, text=True, check=True).stdout
    table: dict[int, tuple[int, str, str]] = {}
    mark = -1
    for line in text.splitlines():
        m = LINE.match(line)
        if m:
            table[int(m.group(1), 16)] = (len(m.group(2).replace(" ", "")) // 2, m.group(3), m.group(4))
        elif s := SYMBOL.match(line):
            mark = int(s.group(1), 16)
    return table, mark


def cycles(mnemonic: str, operands: str, taken: bool) -> int:
    """Worst-case Cortex-M4 cycles of one executed instruction (see the module docstring)."""
    op = mnemonic.split(".")[0]
    branch_cost = 1 + REFILL + WAIT_STATES
    if op.startswith(("push", "pop", "ldm", "stm")):
        n = operands.count(",") + 1 if "{" in operands else 1
        return 1 + n + (REFILL + WAIT_STATES if "pc" in operands and op.startswith(("pop", "ldm")) else 0)
    if op.startswith(("ldrd", "strd")):
        return 3
    if op.startswith(("ldr", "str")):
        return branch_cost + 1 if op.startswith("ldr") and operands.startswith("pc") else 2
    if op in ("udiv", "sdiv"):
        return 12
    if BRANCHES.match(mnemonic) or (op.startswith("mov") and operands.startswith("pc")):
        return branch_cost if taken else 1
    return 1


def ticks(trace: str, elf: str) -> list[tuple[int, int]]:
    """(instructions, worst-case cycles) of each tick between consecutive pairs of bench_mark entries."""
    table, mark = disassemble(elf)
    with open(trace) as f:
        pcs = [int(line.split("/")[1], 16) for line in f if line.startswith("Trace")]
    at = [i for i, pc in enumerate(pcs) if pc == mark]
    out = []
    for a, b in zip(at[0::2], at[1::2], strict=True):
        n = c = 0
        for i in range(a + 1, b):  # after the first bench_mark's bx lr, up to the second bench_mark
            size, mnemonic, operands = table[pcs[i]]
            c += cycles(mnemonic, operands, taken=pcs[i + 1] != pcs[i] + size)
            n += 1
        out.append((n, c + EXCEPTION_CYCLES))
    return out


def main(argv: list[str]) -> int:
    got = ticks(argv[1], argv[2])
    if len(got) != N_TICKS:
        print(f"build_firmware: expected {N_TICKS} measured ticks in the qemu trace, found {len(got)}", file=sys.stderr)
        return 1
    print(f"firmware: per tick (qemu, bench.c: {LEGEND}): instructions {' '.join(str(n) for n, _ in got)}; "
          f"worst-case cycles {' '.join(str(c) for _, c in got)}")
    n, c = max(got, key=lambda t: t[1])
    print(f"firmware: worst tick {n} instructions, {c} cycles (worst-case Cortex-M4 model) = {c / CPU_HZ * 1e6:.0f} µs "
          f"at 84 MHz = {c / CPU_HZ / PERIOD_S:.0%} of a 1 kHz period (on the board, tick_cycles_max holds the measured worst)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
