"""Register models of the STM32F401 peripherals board.c uses (RM0368), each at its bus address.

Every model holds the registers the firmware may touch; an access to any other offset of a peripheral — or to a
peripheral with its bus clock off — is a ``ModelError`` naming the register, never a silent zero. Time is the MCU's
device clock in ns (``Clock``); the timers derive their counters from it, so what the firmware reads is what the
silicon would show at that instant (the CPU itself is modelled as infinitely fast between two interrupts).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

TIMER_HZ = 84_000_000  # TIM2/5 kernel clock with APB1 at 42 MHz (×2), TIM1's with APB2 at 84 MHz: BOARD_TIMER_HZ
LSI_HZ = 32_000  # the IWDG's clock (nominal; RM0368 gives 17–47 kHz)
IRQ_TIM5, IRQ_USART2, IRQ_DMA1_STREAM6 = 50, 38, 17
USART2_DR = 0x40004404


class ModelError(RuntimeError):
    """The firmware did something the board model does not implement (or the silicon would not allow)."""


@dataclass
class Clock:
    now_ns: int = 0


class Peripheral:
    """A block of 32-bit registers at ``base``: ``regs`` offset → value; reads/writes dispatch to hooks."""

    name = "peripheral"
    size = 0x400
    clock_bit: tuple[str, int] | None = None  # (RCC enable register, bit) that must be set to use it

    def __init__(self, base: int, resets: dict[int, int]) -> None:
        self.base = base
        self.regs = dict(resets)

    def reg_name(self, off: int) -> str:
        return f"{self.name}+0x{off:02X}"

    def unknown(self, off: int, what: str) -> ModelError:
        return ModelError(f"board model: {what} of {self.reg_name(off)} (0x{self.base + off:08X}), a register the "
                          "model does not implement")

    def read(self, off: int) -> int:
        if off not in self.regs:
            raise self.unknown(off, "read")
        return self.regs[off]

    def write(self, off: int, value: int) -> None:
        if off not in self.regs:
            raise self.unknown(off, "write")
        self.regs[off] = value


class Rcc(Peripheral):
    """RCC: oscillators ready as soon as enabled (the HSE only if the board has one: ``hse_hz``), SWS follows SW,
    bus clock enables. Switching SYSCLK to the PLL checks the clock tree: the PLL's source running, its input
    1–2 MHz, the VCO 192–432 MHz, SYSCLK the 84 MHz the model's timers count at."""

    name = "RCC"
    CR, PLLCFGR, CFGR, AHB1ENR, APB1ENR, APB2ENR, CSR = 0x00, 0x04, 0x08, 0x30, 0x40, 0x44, 0x74
    HSI_HZ, SYSCLK_HZ = 16_000_000, 84_000_000
    RESET_FLAGS = 0xFE000000  # CSR: LPWR, WWDG, IWDG, SFT, POR, PIN, BOR reset flags (bits 31..25)

    def __init__(self, hse_hz: int | None = None, reset_flags: int = 0x0E000000) -> None:
        """``reset_flags``: CSR's flags at this reset (power-on: POR, PIN, BOR)."""
        super().__init__(0x40023800, {0x00: 0x83, 0x04: 0x24003010, 0x08: 0, 0x30: 0, 0x40: 0, 0x44: 0,
                                      self.CSR: reset_flags & self.RESET_FLAGS})
        self.hse_hz = hse_hz

    def read(self, off: int) -> int:
        v = super().read(off)
        if off == self.CR:  # HSIRDY/HSERDY/PLLRDY follow HSION/HSEON/PLLON (start-up time not modelled)
            hse = (v >> 16 & 1) if self.hse_hz else 0
            v = (v & ~((1 << 1) | (1 << 17) | (1 << 25))) | ((v & 1) << 1) | (hse << 17) | ((v >> 24 & 1) << 25)
        elif off == self.CFGR:
            v = (v & ~0xC) | ((v & 3) << 2)
        return v

    def write(self, off: int, value: int) -> None:
        if off == self.CR and (value ^ self.regs[self.CR]) & (1 << 18) and self.regs[self.CR] & (1 << 16):
            raise ModelError("board model: RCC_CR HSEBYP changed with the HSE on (RM0368: only while HSEON = 0)")
        if off == self.CFGR and value & 3 == 2:
            self.check_pll()
        if off == self.CSR:  # RMVF clears the reset flags; LSIRDY follows LSION
            flags = 0 if value >> 24 & 1 else self.regs[self.CSR] & self.RESET_FLAGS
            value = flags | (value & 1) | ((value & 1) << 1)
        super().write(off, value)

    def pll_source_hz(self) -> int:
        pll, cr = self.regs[self.PLLCFGR], self.regs[self.CR]
        if pll >> 22 & 1:
            if not (self.hse_hz and cr >> 16 & 1):
                raise ModelError("board model: the PLL runs from the HSE, which is " +
                                 ("off" if self.hse_hz else "not fitted on this board"))
            return self.hse_hz
        return self.HSI_HZ

    def check_pll(self) -> None:
        pll = self.regs[self.PLLCFGR]
        m, n, p = pll & 63, pll >> 6 & 511, ((pll >> 16 & 3) + 1) * 2
        if not self.regs[self.CR] >> 24 & 1:
            raise ModelError("board model: SYSCLK switched to the PLL while it is off")
        src = self.pll_source_hz()
        vco_in = src / m if m >= 2 else 0
        if not 1e6 <= vco_in <= 2e6 or not 192e6 <= vco_in * n <= 432e6 or vco_in * n / p != self.SYSCLK_HZ:
            raise ModelError(f"board model: PLL {src / 1e6:g} MHz / M {m} × N {n} / P {p} = "
                             f"{(vco_in * n / p) / 1e6 if m >= 2 else 0:g} MHz; the model runs at 84 MHz "
                             "(input 1–2 MHz, VCO 192–432 MHz)")

    def enabled(self, reg: str, bit: int) -> bool:
        return bool(self.regs[getattr(self, reg)] >> bit & 1)


class Flash(Peripheral):
    name = "FLASH"
    size = 0x400

    def __init__(self) -> None:
        super().__init__(0x40023C00, {0x00: 0})


class Gpio(Peripheral):
    """GPIO port: mode/speed/pull/alternate-function registers, BSRR sets ODR."""

    BSRR, ODR = 0x18, 0x14

    def __init__(self, name: str, base: int, clock_bit: int, moder: int, ospeedr: int, pupdr: int) -> None:
        super().__init__(base, {0x00: moder, 0x04: 0, 0x08: ospeedr, 0x0C: pupdr, 0x10: 0, 0x14: 0, 0x20: 0, 0x24: 0})
        self.name = name
        self.clock_bit = ("AHB1ENR", clock_bit)

    def write(self, off: int, value: int) -> None:
        if off == self.BSRR:
            odr = self.regs[self.ODR]
            self.regs[self.ODR] = (odr | (value & 0xFFFF)) & ~(value >> 16)
            return
        super().write(off, value)

    def mode(self, pin: int) -> int:
        return self.regs[0x00] >> (2 * pin) & 3

    def alternate(self, pin: int) -> int:
        reg = 0x20 if pin < 8 else 0x24
        return self.regs[reg] >> (4 * (pin % 8)) & 15

    def output(self, pin: int) -> bool:
        return bool(self.regs[self.ODR] >> pin & 1)


_TIM_REGS = {0x00: 0, 0x04: 0, 0x08: 0, 0x0C: 0, 0x10: 0, 0x14: 0, 0x18: 0, 0x1C: 0, 0x20: 0, 0x24: 0, 0x28: 0,
             0x2C: 0xFFFFFFFF, 0x34: 0, 0x38: 0, 0x3C: 0, 0x40: 0}


class Timer(Peripheral):
    """A general-purpose timer (or TIM1, the advanced one: ``advanced``, with RCR and BDTR). Up-counting from the
    kernel clock, or the encoder interface (SMS = 1..3) where the count is the plant's; the update event sets UIF
    (and raises ``irq`` with UIE); CCR1 preload (OC1PE) and ARR preload (ARPE) take effect at the update event, as on
    the silicon."""

    CR1, SMCR, DIER, SR, EGR, CCMR1, CCER, CNT, PSC, ARR, CCR1 = 0x00, 0x08, 0x0C, 0x10, 0x14, 0x18, 0x20, 0x24, 0x28, 0x2C, 0x34
    RCR, BDTR = 0x30, 0x44
    MOE, OSSI = 1 << 15, 1 << 10

    def __init__(self, name: str, base: int, clock_bit: int, bits: int, clock: Clock, irq: int | None,
                 raise_irq: Callable[[int], None], advanced: bool = False) -> None:
        super().__init__(base, {**_TIM_REGS, self.RCR: 0, self.BDTR: 0} if advanced else _TIM_REGS)
        self.name = name
        self.advanced = advanced
        self.clock_bit = ("APB2ENR" if advanced else "APB1ENR", clock_bit)
        self.mask = (1 << bits) - 1
        self.regs[self.ARR] = self.mask
        self.clock = clock
        self.irq = irq
        self.raise_irq = raise_irq
        self.t0_ns = 0  # time of the last update event (counter 0), while counting
        self.arr_active = self.mask
        self.ccr1_active = 0
        self.encoder_count: Callable[[], int] | None = None
        self.on_trgo: Callable[[], None] | None = None  # what the trigger output (TRGO) is wired to

    def counting(self) -> bool:
        return bool(self.regs[self.CR1] & 1) and not self.regs[self.SMCR] & 7

    def tick_ns(self) -> float:
        return 1e9 * (self.regs[self.PSC] + 1) / TIMER_HZ

    def count(self) -> int:
        if self.regs[self.SMCR] & 7 in (1, 2, 3):  # encoder interface: the plant's position, wrapping at ARR
            counts = self.encoder_count() if self.encoder_count and self.regs[self.CR1] & 1 else 0
            return counts % ((self.regs[self.ARR] & self.mask) + 1)
        if not self.counting():
            return self.regs[self.CNT]
        return int((self.clock.now_ns - self.t0_ns) / self.tick_ns()) & self.mask

    def oc1_duty(self, outputs_off: bool = False, settled: bool = False) -> float:
        """Share of the PWM period CH1's output is high (PWM mode 1, up-counting): CCR1 / (ARR + 1) in force, 0
        while the counter or CC1E is off; on TIM1 also 0 while the main output is off (MOE clear, or ``outputs_off``:
        a debugger halt with DBG_TIM1_STOP), the output then at its idle level OIS1, which board.c leaves low.
        ``settled``: with the preloads transferred (the duty from the next update event on)."""
        if not self.regs[self.CR1] & 1 or not self.regs[self.CCER] & 1 or self.regs[self.CCMR1] >> 4 & 7 != 6:
            return 0.0
        if self.advanced and (outputs_off or not self.regs[self.BDTR] & self.MOE):
            return 0.0
        ccr, arr = (self.regs[self.CCR1], self.regs[self.ARR]) if settled else (self.ccr1_active, self.arr_active)
        return min(ccr, arr + 1) / (arr + 1)

    def next_update_ns(self) -> int | None:
        """When the next update event happens (None: not counting)."""
        if not self.counting():
            return None
        tick = self.tick_ns()
        if (self.clock.now_ns - self.t0_ns) / tick < self.arr_active + 1:  # from the period's start: the same instant
            return max(self.t0_ns + round((self.arr_active + 1) * tick), self.clock.now_ns + 1)  # whenever it is asked
        cnt = self.count()  # past ARR (a lower ARR written without preload): on to the wrap
        ticks = self.arr_active + 1 - cnt if cnt <= self.arr_active else self.mask + 1 - cnt + self.arr_active + 1
        return self.clock.now_ns + max(1, round(ticks * tick))

    def sync(self) -> None:
        """Update events of a timer without interrupt (TIM1's PWM period) up to now: the preloads transfer."""
        if self.counting() and (self.clock.now_ns - self.t0_ns) / self.tick_ns() >= self.arr_active + 1:
            periods = int((self.clock.now_ns - self.t0_ns) / self.tick_ns()) // (self.arr_active + 1)
            self.t0_ns += round(periods * (self.arr_active + 1) * self.tick_ns())
            self.arr_active = self.regs[self.ARR]
            self.ccr1_active = self.regs[self.CCR1]
            self.regs[self.SR] |= 1

    def update_event(self, at_ns: int, software: bool = False) -> None:
        """Counter reached ARR (or UG): back to 0, preloads transfer, UIF set (not by UG with URS set)."""
        self.t0_ns = at_ns
        self.regs[self.CNT] = 0
        self.arr_active = self.regs[self.ARR]
        self.ccr1_active = self.regs[self.CCR1]
        mms = self.regs[0x04] >> 4 & 7  # CR2.MMS: 0 reset (UG is TRGO), 2 update (every update event is)
        if self.on_trgo is not None and (mms == 2 or (mms == 0 and software)):
            self.on_trgo()
        elif mms not in (0, 2):
            raise ModelError(f"board model: {self.name}_CR2 MMS = {mms}, a trigger output the model lacks")
        if software and self.regs[self.CR1] & (1 << 2):  # URS: only an overflow sets UIF / requests the interrupt
            return
        self.regs[self.SR] |= 1
        if self.irq is not None and self.regs[self.DIER] & 1:
            self.raise_irq(self.irq)

    def read(self, off: int) -> int:
        if off == self.CNT:
            return self.count()
        return super().read(off)

    def write(self, off: int, value: int) -> None:
        if off == self.SR:  # rc_w0: writing 0 clears, 1 leaves
            self.regs[off] &= value
            return
        if off == self.EGR:
            if value & 1:  # UG: reinitialise the counter and transfer the preloads (UIF too unless URS)
                self.update_event(self.clock.now_ns, software=True)
            return
        if off == self.CNT:
            self.t0_ns = self.clock.now_ns - round((value & self.mask) * self.tick_ns())
        if off == self.CR1 and value & 1 and not self.regs[self.CR1] & 1:
            self.t0_ns = self.clock.now_ns - round(self.regs[self.CNT] * self.tick_ns())
        if off == self.CR1 and not value & 1 and self.regs[self.CR1] & 1:
            self.regs[self.CNT] = self.count()
        super().write(off, value)
        if off == self.ARR and not self.regs[self.CR1] & (1 << 7):
            self.arr_active = value & self.mask  # no preload: at once (a lower ARR than CNT runs to the wrap)
        if off == self.CCR1 and not self.regs[self.CCMR1] & (1 << 3):
            self.ccr1_active = value
        if off == self.BDTR and value & (1 << 8 | 1 << 12 | 1 << 14):
            raise ModelError(f"board model: {self.name}_BDTR 0x{value:X}: dead time, break input and automatic "
                             "output enable are not modelled")


class Adc(Peripheral):
    """ADC1 with its injected group: a JSWSTART, or the external trigger JEXTSEL names (with JEXTEN set), converts the
    sequence (JSQ from JL) from ``channel_code`` at that instant; JEOC at once (the 6.5 µs are not modelled)."""

    name = "ADC1"
    clock_bit = ("APB2ENR", 8)
    SR, CR1, CR2, SMPR1, SMPR2, JSQR, JDR1 = 0x00, 0x04, 0x08, 0x0C, 0x10, 0x38, 0x3C

    def __init__(self) -> None:
        super().__init__(0x40012000, {0x00: 0, 0x04: 0, 0x08: 0, 0x0C: 0, 0x10: 0, 0x38: 0, 0x3C: 0, 0x40: 0,
                                      0x44: 0, 0x48: 0, 0x304: 0})  # 0x304: ADC_CCR (common registers)
        self.channel_code: Callable[[int], int] = lambda ch: 0
        self.conversions = 0

    def write(self, off: int, value: int) -> None:
        if off == self.SR:
            self.regs[off] &= value
            return
        if off == self.CR2 and value & (1 << 22):
            if not value & 1:
                raise ModelError("board model: ADC1 injected conversion started with ADON clear")
            if value >> 20 & 3:
                raise ModelError("board model: ADC1 JSWSTART with the injected external trigger enabled (JEXTEN)")
            self.convert_injected()
            value &= ~(1 << 22)
        super().write(off, value)

    def trigger(self, jextsel: int) -> None:
        """An edge of the injected trigger source number ``jextsel`` (RM0368: 11 = TIM5_TRGO)."""
        cr2 = self.regs[self.CR2]
        if cr2 >> 20 & 3 and cr2 >> 16 & 15 == jextsel and cr2 & 1:
            self.convert_injected()

    def convert_injected(self) -> None:
        jsqr = self.regs[self.JSQR]
        n = (jsqr >> 20 & 3) + 1
        for i in range(n):  # with JL = n-1 the sequence is JSQ(4-n+1)..JSQ4, results in JDR1..JDRn
            ch = jsqr >> (5 * (4 - n + i)) & 31
            self.regs[self.JDR1 + 4 * i] = self.channel_code(ch) & 0xFFF
        self.regs[self.SR] |= (1 << 2) | (1 << 3)  # JEOC, JSTRT
        self.conversions += 1


class Usart(Peripheral):
    """USART2: TX bytes leave at once (TXE stays set), RX bytes arrive through ``receive``; RXNE/ORE as RM0368."""

    name = "USART2"
    clock_bit = ("APB1ENR", 17)
    SR, DR, BRR, CR1, CR2, CR3 = 0x00, 0x04, 0x08, 0x0C, 0x10, 0x14
    RXNE, TXE, TC, ORE = 1 << 5, 1 << 7, 1 << 6, 1 << 3

    def __init__(self, raise_irq: Callable[[int], None], tx: bytearray) -> None:
        super().__init__(0x40004400, {0x00: 0xC0, 0x04: 0, 0x08: 0, 0x0C: 0, 0x10: 0, 0x14: 0})
        self.raise_irq = raise_irq
        self.tx = tx  # bytes sent, kept across resets (the host's side of the line)
        self.rx_lost = 0
        self._sr_read = False

    def line(self) -> bool:
        sr, cr1 = self.regs[self.SR], self.regs[self.CR1]
        return bool((sr & self.TXE and cr1 & (1 << 7)) or (sr & (self.RXNE | self.ORE) and cr1 & (1 << 5)))

    def receive(self, byte: int, errors: int = 0) -> None:
        """A byte at the receiver; ``errors``: its PE/FE/NF bits (SR bits 0..2), as a line fault leaves them."""
        if not self.regs[self.CR1] & (1 << 13) or not self.regs[self.CR1] & (1 << 2):
            self.rx_lost += 1  # UE/RE off: the byte is not received
            return
        if self.regs[self.SR] & self.RXNE:
            self.regs[self.SR] |= self.ORE  # the previous byte was not read: this one is lost
            self.rx_lost += 1
        else:
            self.regs[self.DR] = byte
            self.regs[self.SR] |= self.RXNE | (errors & 7)
        if self.line():
            self.raise_irq(IRQ_USART2)

    def read(self, off: int) -> int:
        v = super().read(off)
        if off == self.SR:
            self._sr_read = True
        elif off == self.DR:
            if self._sr_read:  # SR then DR clears ORE/NF/FE
                self.regs[self.SR] &= ~0xF
            self.regs[self.SR] &= ~self.RXNE
            self._sr_read = False
        return v

    def dma_send(self, data: bytes) -> None:
        """Bytes a DMA stream writes to DR on the USART's transmit requests (CR3 DMAT)."""
        if not self.regs[self.CR3] & (1 << 7):
            raise ModelError("board model: a DMA stream writes USART2_DR, and USART2_CR3 DMAT is clear (no requests)")
        for byte in data:
            self.write(self.DR, byte)

    def write(self, off: int, value: int) -> None:
        if off == self.DR:
            if not self.regs[self.CR1] & (1 << 13) or not self.regs[self.CR1] & (1 << 3):
                raise ModelError("board model: USART2_DR written with UE or TE clear")
            self.tx.append(value & 0xFF)
            return
        if off == self.SR:
            self.regs[off] &= value | ~0x60  # only RXNE and TC are rc_w0
            return
        super().write(off, value)
        if off == self.CR1 and self.line():
            self.raise_irq(IRQ_USART2)


class Dma(Peripheral):
    """DMA1 with stream 6 only (channel 4: USART2_TX), memory → USART2_DR, byte-wide, direct mode. Enabling the stream
    hands its NDTR bytes to the USART at once (the USART model sends without byte timing); the stream then stays
    enabled for their time on the line (10 bits a byte at USART2's baud rate, NDTR counting down), clears EN, sets
    TCIF6 and raises its interrupt (TCIE). Any other stream, mode or a reconfiguration while enabled is an error."""

    name = "DMA1"
    clock_bit = ("AHB1ENR", 21)
    LISR, HISR, LIFCR, HIFCR = 0x00, 0x04, 0x08, 0x0C
    S6CR, S6NDTR, S6PAR, S6M0AR, S6M1AR, S6FCR = 0xA0, 0xA4, 0xA8, 0xAC, 0xB0, 0xB4
    EN, TCIE, TCIF6 = 1 << 0, 1 << 4, 1 << 21
    CR_ALLOWED = (7 << 25) | (1 << 10) | (3 << 6) | (1 << 4) | 1  # CHSEL, MINC, DIR, TCIE, EN

    def __init__(self, clock: Clock, usart: Usart, memory: Callable[[int, int], bytes], apb1_hz: int,
                 raise_irq: Callable[[int], None]) -> None:
        super().__init__(0x40026000, {self.LISR: 0, self.HISR: 0, self.LIFCR: 0, self.HIFCR: 0, self.S6CR: 0,
                                      self.S6NDTR: 0, self.S6PAR: 0, self.S6M0AR: 0, self.S6M1AR: 0, self.S6FCR: 0x21})
        self.clock = clock
        self.usart = usart
        self.memory = memory
        self.apb1_hz = apb1_hz
        self.raise_irq = raise_irq
        self.start_ns = 0
        self.done_ns: int | None = None  # the running transfer's end
        self.transfers = 0

    def _byte_ns(self) -> float:
        brr = self.usart.regs[Usart.BRR]
        if not brr:
            raise ModelError("board model: DMA to USART2 with its baud rate (BRR) unset")
        return 10 * brr * 1e9 / self.apb1_hz

    def read(self, off: int) -> int:
        v = super().read(off)
        if off == self.S6NDTR and self.done_ns is not None:  # bytes not yet on the line
            left = self.done_ns - self.clock.now_ns
            v = min(v, math.ceil(left / self._byte_ns())) if left > 0 else 0
        elif off in (self.LIFCR, self.HIFCR):
            v = 0
        return v

    def write(self, off: int, value: int) -> None:
        if off in (self.LIFCR, self.HIFCR):  # write 1 to clear the matching ISR flags
            isr = self.LISR if off == self.LIFCR else self.HISR
            self.regs[isr] &= ~value
            return
        if off in (self.LISR, self.HISR):
            raise ModelError(f"board model: {self.reg_name(off)} is read-only (clear its flags through the IFCR)")
        if off in (self.S6CR, self.S6NDTR, self.S6PAR, self.S6M0AR, self.S6M1AR, self.S6FCR):
            if self.regs[self.S6CR] & self.EN:
                raise ModelError(f"board model: {self.reg_name(off)} written while stream 6 is enabled (RM0368: "
                                 "write-protected until EN reads 0)")
            super().write(off, value)
            if off == self.S6CR and value & self.EN:
                self._start(value)
            return
        raise self.unknown(off, "write")

    def _start(self, cr: int) -> None:
        if cr & ~self.CR_ALLOWED or cr >> 25 & 7 != 4 or cr >> 6 & 3 != 1 or not cr & (1 << 10):
            raise ModelError(f"board model: DMA1 stream 6 enabled with CR 0x{cr:08X}; the model has channel 4 "
                             "(USART2_TX), memory to peripheral, memory increment, byte-wide, direct mode only")
        if self.regs[self.S6PAR] != USART2_DR:
            raise ModelError(f"board model: DMA1 stream 6 writes 0x{self.regs[self.S6PAR]:08X}; the model has "
                             "USART2_DR only")
        if self.regs[self.HISR] & (0x3D << 16):
            raise ModelError("board model: DMA1 stream 6 enabled with its HISR flags set (RM0368: clear them first)")
        n = self.regs[self.S6NDTR] & 0xFFFF
        self.usart.dma_send(self.memory(self.regs[self.S6M0AR], n))
        self.start_ns = self.clock.now_ns
        self.done_ns = self.clock.now_ns + round(n * self._byte_ns())
        self.transfers += 1

    def complete(self) -> None:
        """The last byte has left: EN cleared, NDTR 0, TCIF6, the interrupt if TCIE."""
        self.done_ns = None
        self.regs[self.S6NDTR] = 0
        self.regs[self.S6CR] &= ~self.EN
        self.regs[self.HISR] |= self.TCIF6
        if self.regs[self.S6CR] & self.TCIE:
            self.raise_irq(IRQ_DMA1_STREAM6)


class Iwdg(Peripheral):
    """Independent watchdog: started by 0xCCCC, reloaded by 0xAAAA, PR/RLR writable after 0x5555; expires after
    (RLR + 1) · 4 · 2^PR LSI periods without a reload."""

    name = "IWDG"

    def __init__(self, clock: Clock) -> None:
        super().__init__(0x40003000, {0x00: 0, 0x04: 0, 0x08: 0xFFF, 0x0C: 0})
        self.clock = clock
        self.lsi_hz = LSI_HZ  # its clock: a test may put it anywhere in the datasheet's 17–47 kHz
        self.running = False
        self.unlocked = False
        self.reload_ns = 0
        self.reloads = 0

    def timeout_ns(self) -> int:
        return round((self.regs[0x08] + 1) * 4 * (1 << self.regs[0x04]) * 1e9 / self.lsi_hz)

    def expires_ns(self) -> int | None:
        return self.reload_ns + self.timeout_ns() if self.running else None

    def write(self, off: int, value: int) -> None:
        if off == 0x00:
            key = value & 0xFFFF
            if key == 0xCCCC:
                self.running = True
                self.reload_ns = self.clock.now_ns
            elif key == 0xAAAA:
                self.reload_ns = self.clock.now_ns
                self.reloads += 1
                self.unlocked = False
            elif key == 0x5555:
                self.unlocked = True
            return
        if off in (0x04, 0x08):
            if not self.unlocked:
                raise ModelError(f"board model: {self.reg_name(off)} written without the 0x5555 unlock key")
            super().write(off, value & (7 if off == 0x04 else 0xFFF))
            return
        raise self.unknown(off, "write")
