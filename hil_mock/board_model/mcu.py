"""The STM32F401 running an ELF image: unicorn's Cortex-M4 core, the NVIC and exception entry/return, the peripherals.

Why unicorn: it runs the Thumb-2 code of the very image at native-translation speed and calls back into Python on
every access to a mapped I/O region, so each peripheral register is a few lines of Python with the plant behind
it; qemu 7.2 has no STM32F4 RCC model (the image spins in its clock set-up there) and no way to plug our plant into
its ADC and timers. Unicorn has no NVIC, so this module does exception entry (the 8-word frame, aligned, on the
active stack), priorities and nesting (a higher-priority line raised inside a handler pre-empts it after the current
instruction) and the return (the frame popped when the handler returns to a sentinel address).

Time: ``clock.now_ns`` moves only between interrupts (``advance_to``); the CPU runs each handler to completion in
zero device time. A read of an unmapped address, an access to a register the model lacks, or a handler that does not
return within ``MAX_INSTRUCTIONS`` instructions is a ``ModelError``.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from pathlib import Path

from unicorn import UC_ARCH_ARM, UC_HOOK_CODE, UC_MODE_MCLASS, UC_MODE_THUMB, UC_PROT_ALL, UC_PROT_READ, Uc, UcError
from unicorn.arm_const import (
    UC_ARM_REG_LR,
    UC_ARM_REG_PC,
    UC_ARM_REG_R0,
    UC_ARM_REG_R1,
    UC_ARM_REG_R2,
    UC_ARM_REG_R3,
    UC_ARM_REG_R12,
    UC_ARM_REG_SP,
    UC_ARM_REG_XPSR,
    UC_CPU_ARM_CORTEX_M4,
)

from hil_mock.board_model.peripherals import (
    IRQ_TIM5,
    IRQ_USART2,
    Adc,
    Clock,
    Dma,
    Flash,
    Gpio,
    Iwdg,
    ModelError,
    Peripheral,
    Rcc,
    Timer,
    Usart,
)

FLASH_BASE, FLASH_SIZE = 0x08000000, 256 * 1024
RAM_BASE, RAM_SIZE = 0x20000000, 64 * 1024
SYSMEM_BASE = 0x1FFF0000  # system memory page: the unique id at 0x1FFF7A10, and our return sentinel
UID_ADDR = 0x1FFF7A10
SENTINEL = 0x1FFF0100  # handlers return here (LR): the model pops the exception frame
PERIPH_BASE, PERIPH_SIZE = 0x40000000, 0x30000
PPB_BASE, PPB_SIZE = 0xE0000000, 0x100000
IRQ_COUNT = 86
JEXTSEL_TIM5_TRGO = 11
MAX_INSTRUCTIONS = 5_000_000  # per run of a handler: ~60 ms of CPU at 84 MHz, 100 worst ticks
WFI = 0xBF30
DBGMCU_IDCODE, DBGMCU_CR, DBGMCU_APB1_FZ, DBGMCU_APB2_FZ = 0xE0042000, 0xE0042004, 0xE0042008, 0xE004200C
IDCODE_F401 = 0x10006433  # REV_ID 0x1000, DEV_ID 0x433 (STM32F401xD/E)
FRAME_REGS = (UC_ARM_REG_R0, UC_ARM_REG_R1, UC_ARM_REG_R2, UC_ARM_REG_R3, UC_ARM_REG_R12, UC_ARM_REG_LR)
ENTRY_REGS = (*FRAME_REGS, UC_ARM_REG_PC, UC_ARM_REG_XPSR, UC_ARM_REG_SP)


def load_elf(path: Path) -> tuple[list[tuple[int, bytes]], dict[str, int]]:
    """(load address, bytes) of each PT_LOAD segment (at its physical address: .data's image in flash) and the
    symbol table (name → value) of a 32-bit little-endian ARM ELF."""
    data = path.read_bytes()
    if data[:4] != b"\x7fELF" or data[4] != 1 or data[5] != 1:
        raise ModelError(f"{path}: not a 32-bit little-endian ELF")
    e_phoff, e_shoff = struct.unpack_from("<II", data, 28)
    e_phentsize, e_phnum, e_shentsize, e_shnum = struct.unpack_from("<HHHH", data, 42)
    segments = []
    for i in range(e_phnum):
        p_type, p_offset, _vaddr, p_paddr, p_filesz = struct.unpack_from("<IIIII", data, e_phoff + i * e_phentsize)
        if p_type == 1 and p_filesz:
            segments.append((p_paddr, data[p_offset:p_offset + p_filesz]))
    entries: list[tuple[bool, str, int]] = []
    sections = [struct.unpack_from("<IIIIIIIIII", data, e_shoff + i * e_shentsize) for i in range(e_shnum)]
    for sh in sections:
        if sh[1] != 2:  # SHT_SYMTAB
            continue
        strtab = sections[sh[6]]
        for off in range(sh[4], sh[4] + sh[5], 16):
            name_off, value, _size, info = struct.unpack_from("<IIIB", data, off)
            end = data.index(b"\0", strtab[4] + name_off)
            name = data[strtab[4] + name_off:end].decode()
            if name and not name.startswith("$"):
                entries.append((info >> 4 == 2, name, value))  # STB_WEAK
    symbols: dict[str, int] = {}
    for _weak, name, value in sorted(entries, key=lambda e: e[0]):  # a weak alias never names its target's code
        symbols.setdefault(name, value)
    return segments, symbols


class Stm32f401:
    """The MCU: core + memory + peripherals. ``reset()`` runs the image from its reset vector to its idle ``wfi``;
    ``advance_to(t_ns)`` lets device time pass (timer updates, the watchdog) and runs the handlers they raise;
    ``receive(data)`` delivers bytes to USART2's receiver; ``usart.tx`` collects what it sent."""

    def __init__(self, image: Path, uid: tuple[int, int, int] = (0x00470032, 0x31345111, 0x30353235),
                 hse_hz: int | None = 8_000_000) -> None:
        """``hse_hz``: the board's external clock (the Nucleo's 8 MHz from the ST-LINK; None: none fitted)."""
        self.image = image
        self.hse_hz = hse_hz
        self.segments, self.symbols = load_elf(image)
        self.uid = uid
        self.clock = Clock()
        self.tx = bytearray()
        self.adc_code: Callable[[int], int] = lambda ch: 2048  # 12-bit code of an ADC channel at conversion
        self.encoder: Callable[[], int] = lambda: 0  # quadrature count at TIM2's inputs
        self.theta_encoder: Callable[[], int] = self._no_theta_encoder  # counts at TIM4's (PB6/PB7) since power-up
        self.resets = 0
        self.watchdog_resets = 0
        self.on_reset: Callable[[], None] | None = None
        self._reset_flags = 0x0E000000  # RCC_CSR at the next reset: power-on
        self._stalls: dict[int, list[int]] = {}  # code address → [device ns it takes, calls left (-1: all)]
        self.dbgmcu = {DBGMCU_CR: 0, DBGMCU_APB1_FZ: 0, DBGMCU_APB2_FZ: 0}  # debug domain: kept across a system reset
        self._build()

    # ------------------------------------------------------------ construction
    def _build(self) -> None:
        self.rcc = Rcc(self.hse_hz, self._reset_flags)
        self.gpioa = Gpio("GPIOA", 0x40020000, 0, 0xA8000000, 0x0C000000, 0x64000000)
        self.gpiob = Gpio("GPIOB", 0x40020400, 1, 0x00000280, 0x000000C0, 0x00000100)
        self.tim2 = Timer("TIM2", 0x40000000, 0, 32, self.clock, None, self.raise_irq)
        self.tim1 = Timer("TIM1", 0x40010000, 0, 16, self.clock, None, self.raise_irq, advanced=True)
        self.tim4 = Timer("TIM4", 0x40000800, 2, 16, self.clock, None, self.raise_irq)
        self.tim5 = Timer("TIM5", 0x40000C00, 3, 32, self.clock, IRQ_TIM5, self.raise_irq)
        self.adc = Adc()
        self.adc.channel_code = lambda ch: self.adc_code(ch)
        self.tim5.on_trgo = lambda: self.adc.trigger(JEXTSEL_TIM5_TRGO)
        self.tim2.encoder_count = lambda: self.encoder()
        self.tim4.encoder_count = lambda: self.theta_encoder()
        self.usart = Usart(self.raise_irq, self.tx)
        self.dma = Dma(self.clock, self.usart, self._sram, 42_000_000, self.raise_irq)
        self.iwdg = Iwdg(self.clock)
        self.flash = Flash()
        periph: list[Peripheral] = [self.rcc, self.gpioa, self.gpiob, self.tim1, self.tim2, self.tim4, self.tim5, self.adc,
                                    self.usart, self.dma, self.iwdg, self.flash]
        self._by_page = {p.base >> 10: p for p in periph}
        self._by_page[0x40012300 >> 10] = self.adc  # ADC common registers (ADC_CCR) share ADC1's model
        self.nvic_enabled = [False] * IRQ_COUNT
        self.nvic_pending = [False] * IRQ_COUNT
        self.nvic_priority = [0] * IRQ_COUNT
        self.active: list[int] = []  # exception numbers being handled, innermost last
        self.demcr = 0
        self.dwt_ctrl = 0x40000000
        self.halted = False  # a debugger holds the core (debug_halt)
        self.dwt_cyccnt_base = 0
        self.asleep = False
        self.error: Exception | None = None
        self._preempt = False

        uc = self.uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        uc.ctl_set_cpu_model(UC_CPU_ARM_CORTEX_M4)
        uc.mem_map(FLASH_BASE, FLASH_SIZE, UC_PROT_ALL)
        uc.mem_map(RAM_BASE, RAM_SIZE, UC_PROT_ALL)
        uc.mem_map(SYSMEM_BASE, 0x8000, UC_PROT_ALL)
        for addr, blob in self.segments:
            if not FLASH_BASE <= addr < FLASH_BASE + FLASH_SIZE:
                raise ModelError(f"{self.image}: a segment loads at 0x{addr:08X}, outside the F401's flash")
            uc.mem_write(addr, blob)
        uc.mem_write(UID_ADDR, struct.pack("<III", *self.uid))
        uc.mem_write(SENTINEL, struct.pack("<H", 0xE7FE))  # b . (never executed: emulation stops before it)
        uc.mem_protect(SYSMEM_BASE, 0x8000, UC_PROT_READ | 4)
        uc.mmio_map(PERIPH_BASE, PERIPH_SIZE, self._periph_read, None, self._periph_write, None)
        uc.mmio_map(PPB_BASE, PPB_SIZE, self._ppb_read, None, self._ppb_write, None)
        flash = uc.mem_read(FLASH_BASE, FLASH_SIZE)
        main, end = self.symbols.get("main"), self.symbols.get("__aeabi_uldivmod", FLASH_BASE + FLASH_SIZE)
        if main is None:
            raise ModelError(f"{self.image}: no symbol 'main'")
        main &= ~1
        for addr in range(main, min(end, main + 0x1000), 2):  # the idle loop's wfi: the thread is asleep there
            if struct.unpack_from("<H", flash, addr - FLASH_BASE)[0] == WFI:
                uc.hook_add(UC_HOOK_CODE, self._on_wfi, begin=addr, end=addr)
        for addr in self._stalls:
            uc.hook_add(UC_HOOK_CODE, self._on_stall, begin=addr, end=addr)

    def _sram(self, addr: int, n: int) -> bytes:
        """What a DMA stream reads: ``n`` bytes of SRAM at ``addr`` (anything else is an error)."""
        if not RAM_BASE <= addr <= RAM_BASE + RAM_SIZE - n:
            raise ModelError(f"board model: a DMA stream reads 0x{addr:08X}..+{n}, outside the SRAM")
        return bytes(self.uc.mem_read(addr, n))

    @staticmethod
    def _no_theta_encoder() -> int:
        raise ModelError("board model: TIM4 (a pendulum encoder on PB6/PB7) read, and this board has none wired: "
                         "set Stm32f401.theta_encoder")

    def _on_wfi(self, uc: Uc, address: int, size: int, user: object) -> None:
        self.asleep = True
        uc.emu_stop()

    def stall(self, symbol: str, ns: int, times: int = -1) -> None:
        """Each time the CPU enters function ``symbol``, ``ns`` of device time pass there — that code (or an interrupt
        it waited for) taking that long — with TIM5's update events falling due inside, UIF and the NVIC pending bit
        set as on the silicon (the model's CPU is otherwise infinitely fast). ``times``: only the next ``times`` calls.
        Only the tick's code may stall: TIM5 must not pre-empt what stalls."""
        if symbol not in self.symbols:
            raise ModelError(f"{self.image}: no symbol {symbol!r} to stall")
        addr = self.symbols[symbol] & ~1
        if addr not in self._stalls:
            self.uc.hook_add(UC_HOOK_CODE, self._on_stall, begin=addr, end=addr)
        self._stalls[addr] = [ns, times]

    def trace(self) -> list[int]:
        """Record the address of every instruction executed in flash from now on (the list returned fills) until
        ``untrace``: the executed sequence scripts/firmware_ticks.py's cycle model prices. Not across a reset."""
        pcs: list[int] = []
        self._trace_hook = self.uc.hook_add(UC_HOOK_CODE, lambda uc, addr, size, user: pcs.append(addr),
                                            begin=FLASH_BASE, end=FLASH_BASE + FLASH_SIZE - 1)
        return pcs

    def untrace(self) -> None:
        self.uc.hook_del(self._trace_hook)

    def _on_stall(self, uc: Uc, address: int, size: int, user: object) -> None:
        entry = self._stalls[address]
        if entry[1] == 0:
            return
        entry[1] -= entry[1] > 0
        end = self.clock.now_ns + entry[0]
        while (t := self.tim5.next_update_ns()) is not None and t <= end:
            self.clock.now_ns = t
            self._sync_pwm()
            self.tim5.update_event(t)
        self.clock.now_ns = end
        self._sync_pwm()

    # ------------------------------------------------------------ memory-mapped I/O
    def _fail(self, err: Exception) -> int:
        if self.error is None:
            self.error = err
        self.uc.emu_stop()
        return 0

    def _peripheral(self, addr: int) -> Peripheral:
        p = self._by_page.get(addr >> 10)
        if p is None:
            raise ModelError(f"board model: access to 0x{addr:08X}, a peripheral the model does not implement")
        if p.clock_bit is not None and not self.rcc.enabled(*p.clock_bit):
            raise ModelError(f"board model: {p.name} accessed with its clock off (RCC {p.clock_bit[0]} bit "
                             f"{p.clock_bit[1]}): the silicon ignores the write / reads 0")
        return p

    def _periph_read(self, uc: Uc, offset: int, size: int, user: object) -> int:
        addr = PERIPH_BASE + offset
        try:
            p = self._peripheral(addr)
            if size != 4 and p is not self.gpioa and p is not self.gpiob:
                raise ModelError(f"board model: {size}-byte read of {p.reg_name(addr - p.base)}")
            value = p.read((addr & ~3) - p.base)
            return value >> (8 * (addr & 3)) & ((1 << (8 * size)) - 1)
        except ModelError as err:
            return self._fail(err)

    def _periph_write(self, uc: Uc, offset: int, size: int, value: int, user: object) -> None:
        addr = PERIPH_BASE + offset
        try:
            p = self._peripheral(addr)
            if size != 4:
                raise ModelError(f"board model: {size}-byte write of {p.reg_name(addr - p.base)}")
            p.write(addr - p.base, value & 0xFFFFFFFF)
            self._check_preempt()
        except ModelError as err:
            self._fail(err)

    def _ppb_read(self, uc: Uc, offset: int, size: int, user: object) -> int:
        addr = PPB_BASE + offset
        try:
            if addr == 0xE0001004:
                return self.cycles() & 0xFFFFFFFF
            if addr == 0xE0001000:
                return self.dwt_ctrl
            if addr == 0xE000EDFC:
                return self.demcr
            if addr == DBGMCU_IDCODE:
                return IDCODE_F401
            if addr in self.dbgmcu:
                return self.dbgmcu[addr]
            nvic = self._nvic_bits(addr)
            if nvic is not None:
                bits, n = nvic
                return sum(1 << i for i in range(32) if 32 * n + i < IRQ_COUNT and bits[32 * n + i])
            if 0xE000E400 <= addr < 0xE000E400 + IRQ_COUNT:
                return sum(self.nvic_priority[addr - 0xE000E400 + i] << (8 * i) for i in range(size)
                           if addr - 0xE000E400 + i < IRQ_COUNT)
            raise ModelError(f"board model: read of 0x{addr:08X} (system control space), not modelled")
        except ModelError as err:
            return self._fail(err)

    def _nvic_bits(self, addr: int) -> tuple[list[bool], int] | None:
        for base, bits in ((0xE000E100, self.nvic_enabled), (0xE000E180, self.nvic_enabled),
                           (0xE000E200, self.nvic_pending), (0xE000E280, self.nvic_pending)):
            if base <= addr < base + 12 and addr % 4 == 0:
                return bits, (addr - base) // 4
        return None

    def _ppb_write(self, uc: Uc, offset: int, size: int, value: int, user: object) -> None:
        addr = PPB_BASE + offset
        try:
            if addr == 0xE0001004:
                self.dwt_cyccnt_base += (value - self.cycles()) & 0xFFFFFFFF
            elif addr == 0xE0001000:
                self.dwt_ctrl = value
            elif addr == 0xE000EDFC:
                self.demcr = value
            elif addr in self.dbgmcu:
                self.dbgmcu[addr] = value
            elif (nvic := self._nvic_bits(addr)) is not None:
                bits, n = nvic
                setting = addr < 0xE000E180 or 0xE000E200 <= addr < 0xE000E280
                for i in range(32):
                    if value >> i & 1 and 32 * n + i < IRQ_COUNT:
                        bits[32 * n + i] = setting
                self._check_preempt()
            elif 0xE000E400 <= addr < 0xE000E400 + IRQ_COUNT:
                for i in range(size):
                    if addr - 0xE000E400 + i < IRQ_COUNT:
                        self.nvic_priority[addr - 0xE000E400 + i] = value >> (8 * i) & 0xF0  # 4 bits implemented
            else:
                raise ModelError(f"board model: write of 0x{value:X} to 0x{addr:08X} (system control space), "
                                 "not modelled")
        except ModelError as err:
            self._fail(err)

    def cycles(self) -> int:
        """DWT_CYCCNT: CPU cycles of device time (84 MHz) while enabled (TRCENA and CYCCNTENA)."""
        if not (self.demcr >> 24 & 1 and self.dwt_ctrl & 1):
            return self.dwt_cyccnt_base
        return (self.clock.now_ns * 84 // 1000 + self.dwt_cyccnt_base) & 0xFFFFFFFF

    # ------------------------------------------------------------ interrupts
    def raise_irq(self, irq: int) -> None:
        self.nvic_pending[irq] = True
        self._check_preempt()

    def _execution_priority(self) -> int:
        if not self.active:
            return 256
        return min(-1 if e < 16 else self.nvic_priority[e - 16] for e in self.active)

    def _next_irq(self) -> int | None:
        """The pending, enabled line of highest priority (lowest number) that pre-empts the running code."""
        if True not in self.nvic_pending:
            return None
        prio = self._execution_priority()
        ready = [i for i, p in enumerate(self.nvic_pending) if p and self.nvic_enabled[i] and self.nvic_priority[i] < prio]
        return min(ready, key=lambda i: (self.nvic_priority[i], i)) if ready else None

    def _check_preempt(self) -> None:
        """Called from a register write: a higher line now pending pre-empts after this instruction. Unicorn stops
        with the PC on the store whose callback stopped it (its effect already applied), so ``_run`` resumes after
        it (a peripheral store is a plain STR: no write-back, not in an IT block, in board.c's code)."""
        if self.active and not self._preempt and self._next_irq() is not None:
            self._preempt = True
            self.uc.emu_stop()

    def _reg(self, r: int) -> int:
        return self.uc.reg_read(r)

    def _take(self, exc: int) -> None:
        """Exception entry, run the handler to its return, exception return (pre-empted by higher lines)."""
        uc = self.uc
        vector = struct.unpack("<I", uc.mem_read(FLASH_BASE + 4 * exc, 4))[0]
        *saved, pc, xpsr, sp = uc.reg_read_batch(ENTRY_REGS)  # one call: the emulator's register API is the cost
        align = sp & 4
        sp = (sp - align) - 32
        frame = [*saved, pc, (xpsr | (1 << 9 if align else 0)) | (1 << 24)]
        uc.mem_write(sp, struct.pack("<8I", *frame))
        uc.reg_write_batch(((UC_ARM_REG_SP, sp), (UC_ARM_REG_LR, SENTINEL | 1)))
        if exc >= 16:
            self.nvic_pending[exc - 16] = False
        self.active.append(exc)
        self._run(vector & ~1)
        self.active.pop()
        sp = self._reg(UC_ARM_REG_SP)
        regs = struct.unpack("<8I", uc.mem_read(sp, 32))
        uc.reg_write_batch((*zip(FRAME_REGS, regs[:6], strict=True),
                            (UC_ARM_REG_SP, sp + 32 + (4 if regs[7] >> 9 & 1 else 0)), (UC_ARM_REG_PC, regs[6] | 1),
                            (UC_ARM_REG_XPSR, (regs[7] & 0xF80F0000) | (self.active[-1] if self.active else 0) | (1 << 24))))
        self._relevel()

    def _relevel(self) -> None:
        """Level-sensitive lines still asserted after a handler: pending again (USART2's TXE with TXEIE)."""
        if self.usart.line():
            self.nvic_pending[IRQ_USART2] = True

    def _run(self, pc: int) -> None:
        """Execute from ``pc`` until the sentinel (a handler's return) or the idle wfi (thread mode)."""
        while True:
            self._preempt = False
            self.asleep = False
            try:
                self.uc.emu_start(pc | 1, SENTINEL, timeout=0, count=MAX_INSTRUCTIONS)
            except UcError as err:
                pc_now = self._reg(UC_ARM_REG_PC)
                raise ModelError(f"board model: the CPU stopped at 0x{pc_now:08X} ({self.symbol_at(pc_now)}): {err}") \
                    from None
            if self.error is not None:
                err, self.error = self.error, None
                raise err
            pc = self._reg(UC_ARM_REG_PC)
            if pc == SENTINEL or self.asleep:
                return
            if self._preempt:
                first = struct.unpack("<H", self.uc.mem_read(pc, 2))[0]
                self.uc.reg_write(UC_ARM_REG_PC, (pc + (4 if first >> 11 in (0x1D, 0x1E, 0x1F) else 2)) | 1)
                while (irq := self._next_irq()) is not None:
                    self._take(16 + irq)
                pc = self._reg(UC_ARM_REG_PC)
                continue
            raise ModelError(f"board model: {self.symbol_at(pc)} (0x{pc:08X}) still running after "
                             f"{MAX_INSTRUCTIONS} instructions: the firmware is stuck")

    def symbol_at(self, addr: int) -> str:
        best, name = -1, "?"
        for sym, value in self.symbols.items():
            v = value & ~1
            if FLASH_BASE <= v <= addr and v > best:
                best, name = v, sym
        return name

    def hard_fault(self) -> None:
        """A HardFault now (what a bus error, an undefined instruction or a stack overflow raises on the silicon)."""
        self._take(3)

    def deliver(self) -> None:
        """Take every pending interrupt the current priority allows (from the idle thread)."""
        while (irq := self._next_irq()) is not None:
            self._take(16 + irq)

    # ------------------------------------------------------------ the board's life
    def reset(self, cause: str = "power") -> None:
        """A reset (``cause``: "power" the first time, "watchdog" when the IWDG expires, "pin" the reset button):
        registers to their reset values, RCC_CSR's flags set as the cause sets them (and kept until the firmware
        clears them), the SRAM kept but by a power-on, run from the reset vector to idle."""
        ram = None
        if self.resets:
            kept = self.rcc.regs[Rcc.CSR] & Rcc.RESET_FLAGS
            self._reset_flags = kept | {"power": 0x0E000000, "watchdog": 0x24000000, "pin": 0x04000000}[cause]
            if cause != "power":  # a system reset keeps the SRAM's content (what start-up does not clear survives)
                ram = bytes(self.uc.mem_read(RAM_BASE, RAM_SIZE))
        self.uc.emu_stop()
        cyc = self.cycles()
        uc_old = getattr(self, "uc", None)
        self._build()
        del uc_old
        if ram is not None:
            self.uc.mem_write(RAM_BASE, ram)
        self.dwt_cyccnt_base = cyc  # CYCCNT is in the debug domain; no matter, board.c zeroes it
        self.resets += 1
        sp, pc = struct.unpack("<II", self.uc.mem_read(FLASH_BASE, 8))
        self.uc.reg_write(UC_ARM_REG_SP, sp)
        self._run(pc & ~1)
        if not self.asleep:
            raise ModelError("board model: main() returned")
        if self.on_reset is not None:
            self.on_reset()

    def receive(self, data: bytes) -> None:
        for byte in data:
            self.usart.receive(byte)
            self.deliver()

    def advance_to(self, t_ns: int) -> None:
        """Let device time run to ``t_ns``: timer update events and the watchdog in time order, handlers run (none
        while a debugger holds the core: the lines stay pending)."""
        while True:
            frozen = self._frozen()
            t_upd = None if frozen["TIM5"] else self.tim5.next_update_ns()
            t_wdg = None if frozen["IWDG"] else self.iwdg.expires_ns()
            t_dma = self.dma.done_ns
            t_next = min(t for t in (t_upd, t_wdg, t_dma, t_ns + 1) if t is not None)
            if t_next > t_ns:
                break
            self._move_to(max(self.clock.now_ns, t_next))  # a watchdog that expired inside a stalled handler
            if t_wdg is not None and t_next == t_wdg:
                self.watchdog_resets += 1
                self.halted = False
                self.reset("watchdog")
                continue
            if t_dma is not None and t_next == t_dma:  # a transfer's last byte left: its interrupt
                self.dma.complete()
                if not self.halted:
                    self.deliver()
                if t_next != t_upd:  # an update due at the same instant follows (its time is not asked again:
                    continue  # at the update's instant the count has reached ARR + 1)
            self.tim5.update_event(t_next)
            if not self.halted:
                self.deliver()
        self._move_to(max(self.clock.now_ns, t_ns))

    def _move_to(self, t_ns: int) -> None:
        """Device time to ``t_ns``; while halted, what DBGMCU freezes does not see it pass."""
        dt = t_ns - self.clock.now_ns
        frozen = self._frozen()
        for tim in (self.tim1, self.tim5):
            if frozen[tim.name]:
                tim.t0_ns += dt
        if frozen["IWDG"]:
            self.iwdg.reload_ns += dt
        self.clock.now_ns = t_ns
        self._sync_pwm()

    def _frozen(self) -> dict[str, bool]:
        """What does not count while the core is halted: DBGMCU_APB1_FZ DBG_TIM5_STOP (bit 3), DBG_IWDG_STOP (12);
        DBGMCU_APB2_FZ DBG_TIM1_STOP (0). Nothing while the core runs."""
        apb1, apb2 = (self.dbgmcu[DBGMCU_APB1_FZ], self.dbgmcu[DBGMCU_APB2_FZ]) if self.halted else (0, 0)
        return {"TIM1": bool(apb2 & 1), "TIM5": bool(apb1 >> 3 & 1),
                "IWDG": bool(apb1 >> 12 & 1)}

    def _sync_pwm(self) -> None:
        self.tim1.sync()

    def debug_halt(self) -> None:
        """A debugger stops the core (between two interrupts): no handler runs until ``debug_resume``; the timers and
        the IWDG run on unless the firmware set their DBGMCU freeze bits (TIM1's outputs then go off, as MOE = 0)."""
        self.halted = True

    def debug_resume(self) -> None:
        self.halted = False
        self.deliver()

    def tim1_outputs_off(self) -> bool:
        """TIM1's outputs disabled by a debugger halt with DBG_TIM1_STOP (RM0368: as if MOE were reset)."""
        return self._frozen()["TIM1"]

    def pause(self, dt_ns: int) -> None:
        """The whole board held for ``dt_ns`` (timers, watchdog and cycle counter frozen): device time moves on."""
        self.clock.now_ns += dt_ns
        for tim in (self.tim1, self.tim2, self.tim5):
            tim.t0_ns += dt_ns
        self.iwdg.reload_ns += dt_ns
        self.dwt_cyccnt_base -= dt_ns * 84 // 1000

    def next_tick_ns(self) -> int | None:
        return self.tim5.next_update_ns()
