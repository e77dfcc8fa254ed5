"""The flashed image on the register-level STM32F401 model (hil_mock.board_model): the very furuta_fw.elf that
scripts/build_firmware makes runs on unicorn's Cortex-M4 with models of the peripherals board.c uses.

* Boot at register level: the clock tree, the tick timer, the watchdog and the pins as board.c leaves them.
* A register the model does not implement is an error naming it, never a silent zero.
* `furuta-rt run --mock --mock-firmware board` balances the simulated pendulum through the image for 10 s, with a
  log read back by the mcap package's reader.

Needs arm-none-eabi-gcc and picolibc (scripts/build_firmware, run first by scripts/test, installs them); skipped
without them, as the other firmware tests.
"""

from __future__ import annotations

import itertools
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader
from test_reliability_harness import LOCKSTEP, DaemonProcess, read_summary, traceback_free

from firmware_protocol import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Config,
    Hello,
    HelloAck,
    Sample,
    Status,
    StatusFlags,
    StreamDecoder,
    encode,
)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def image() -> Path:
    if shutil.which("arm-none-eabi-gcc") is None:
        pytest.skip("arm-none-eabi-gcc not installed; scripts/build_firmware installs it (as root with apt-get)")
    from hil_mock.board_model.device import image_path

    elf = image_path()
    if not elf.is_file():
        res = subprocess.run([str(ROOT / "scripts" / "build_firmware")], capture_output=True, text=True, timeout=600,
                             check=False)
        if res.returncode == 77:
            pytest.skip(res.stderr.strip())
        assert res.returncode == 0, res.stderr
    return elf


def test_the_image_boots_on_the_register_model(image: Path) -> None:
    """Reset to the idle wfi: 84 MHz from the PLL fed by the Nucleo's 8 MHz external clock (HSE bypass), TIM5
    ticking at 500 Hz with its interrupt, the IWDG at 50 ms, TIM2 in encoder mode, TIM1 at 20 kHz with zero duty and
    its main output on, DIR an output driven low."""
    from hil_mock.board_model.mcu import Stm32f401

    mcu = Stm32f401(image)
    mcu.reset()
    assert mcu.asleep and mcu.resets == 1
    assert mcu.rcc.read(mcu.rcc.CFGR) & 0xC == 0x8  # SWS = PLL
    pll = mcu.rcc.read(mcu.rcc.PLLCFGR)
    assert (pll & 63, pll >> 6 & 511, ((pll >> 16 & 3) + 1) * 2) == (8, 336, 4)  # 8 MHz / 8 × 336 / 4 = 84 MHz
    assert pll >> 22 & 1 and mcu.rcc.read(mcu.rcc.CR) >> 16 & 7 == 0b111  # PLLSRC = HSE; HSEON, HSERDY, HSEBYP
    assert mcu.next_tick_ns() == 2_000_000 and mcu.nvic_enabled[50] and mcu.nvic_enabled[38]
    assert mcu.iwdg.running and mcu.iwdg.timeout_ns() == 51_000_000  # (50 + 1) × 32 / 32 kHz
    assert mcu.tim2.regs[mcu.tim2.SMCR] & 7 == 3 and mcu.tim1.regs[mcu.tim1.ARR] + 1 == 84_000_000 // 20_000
    assert mcu.tim1.regs[mcu.tim1.CCR1] == 0 and mcu.tim1.regs[mcu.tim1.BDTR] & mcu.tim1.MOE
    assert mcu.gpioa.mode(8) == 2 and mcu.gpioa.alternate(8) == 1  # PA8 = TIM1_CH1
    assert mcu.gpioa.mode(7) == 1 and not mcu.gpioa.output(7)


def test_a_handshake_and_samples_through_the_pins(image: Path) -> None:
    """HELLO in on USART2's receiver, HELLO_ACK and SAMPLEs out on its transmitter; the SAMPLE carries the ADC codes
    and the encoder count the model put on the pins (12-bit code − 2048), t_us the TIM5 period."""
    from hil_mock.board_model.mcu import Stm32f401

    mcu = Stm32f401(image)
    mcu.adc_code = lambda ch: {4: 2048 + 100, 8: 2048 - 7}[ch]
    mcu.encoder = lambda: -12345
    mcu.reset()
    mcu.receive(b"\x00" + encode(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0xC0FFEE)))
    for _ in range(3):
        mcu.advance_to(mcu.next_tick_ns())
    msgs = StreamDecoder().feed(bytes(mcu.tx))
    ack = msgs[0]
    assert isinstance(ack, HelloAck) and ack.nonce == 0xC0FFEE and ack.sample_rate_hz == 500
    samples = [m for m in msgs if isinstance(m, Sample)]
    assert [s.seq for s in samples] == [0, 1, 2]  # the HELLO is decoded at the first tick, which streams
    assert (samples[0].theta_adc, samples[0].theta_dot_adc, samples[0].phi_count) == (100, -7, -12345)
    assert samples[1].t_us - samples[0].t_us == 2000


def test_a_register_the_model_lacks_is_an_error_naming_it(image: Path) -> None:
    """Take ADC1_JSQR out of the model: the image's write to it stops the run with the register's name."""
    from hil_mock.board_model.mcu import Stm32f401
    from hil_mock.board_model.peripherals import Adc, ModelError

    class AdcWithoutJsqr(Adc):
        def write(self, off: int, value: int) -> None:
            if off == self.JSQR:
                raise self.unknown(off, "write")
            super().write(off, value)

    mcu = Stm32f401(image)
    build = mcu._build

    def build_without() -> None:
        build()
        mcu.adc = AdcWithoutJsqr()
        mcu._by_page[mcu.adc.base >> 10] = mcu.adc

    mcu._build = build_without  # type: ignore[method-assign]
    with pytest.raises(ModelError, match=r"ADC1\+0x38 \(0x40012038\)"):
        mcu.reset()


@pytest.mark.hil
def test_the_daemon_balances_through_the_flashed_image(image: Path, tmp_path: Path) -> None:
    """`furuta-rt run --mock --mock-firmware board` with the macstepien rig (an H-bridge-driven dc motor, as the
    board's 12 V PWM + DIR output): the real image, lockstep-paced, balances for 4 s of device time (the register-level
    model runs slower than real time; a longer run balances the same way and checks nothing more)."""
    log = tmp_path / "run.mcap"
    d = DaemonProcess(["--mock", "--mock-firmware", "board", "--config", "macstepien", "--duration", "4", "--no-tui",
                       LOCKSTEP, "--log", str(log), "--summary-json", str(tmp_path / "summary.json")])
    rc = d.wait(timeout=280)
    assert traceback_free(d.stderr + d.stdout), d.stderr
    assert rc == 0, f"exit {rc}\n{d.stderr}\n{d.stdout}"
    assert "firmware 0.3.0" in d.stdout + d.stderr
    s = read_summary(tmp_path)
    assert s["end"] == "duration" and s["ticks"] == 4 * 500 and s["balanced_s"] > 3.9
    with log.open("rb") as fh:
        reader = make_reader(fh)
        topics = {ch.topic for ch in reader.get_summary().channels.values()}
        n = sum(st for st in reader.get_summary().statistics.channel_message_counts.values())
    assert topics and n >= 4 * 500


def _samples_with(image: Path, theta_code: int, theta_dot_code: int, ticks: int = 3) -> list[Sample]:
    from hil_mock.board_model.mcu import Stm32f401

    mcu = Stm32f401(image)
    mcu.adc_code = lambda ch: {4: theta_code, 8: theta_dot_code}[ch]
    mcu.reset()
    mcu.receive(b"\x00" + encode(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 1)))
    for _ in range(ticks):
        mcu.advance_to(mcu.next_tick_ns())
    return [m for m in StreamDecoder().feed(bytes(mcu.tx)) if isinstance(m, Sample)]


def test_a_wrapping_theta_sensor_at_its_wrap_is_not_over_range(image: Path) -> None:
    """The pendulum hanging reads θ at the wrap of a full-turn sensor (12-bit code 0 and 4095 alternate with noise):
    no ADC_OVERRANGE, which would forbid the swing-up; θ̇ (an analog rate that saturates) at a rail still latches it."""
    over = int(StatusFlags.ADC_OVERRANGE)
    for code in (0, 4095):
        assert not any(s.status & over for s in _samples_with(image, code, 2048)), code
    assert all(s.status & over for s in _samples_with(image, 2048, 0))


def test_a_direction_change_never_drives_the_old_duty_the_new_way(image: Path) -> None:
    """TIM1's duty is preloaded (it takes effect at the PWM period's end) while DIR is a plain pin: a reversal must
    not leave the old duty running in the new direction. Right after the tick that reverses +16000 to −16000, the
    duty TIM1 is driving is 0; the new one takes over at the next PWM period."""
    from firmware_protocol import Command, CommandFlags
    from hil_mock.board_model.mcu import Stm32f401

    mcu = Stm32f401(image)
    mcu.adc_code = lambda ch: 2048
    mcu.reset()
    mcu.receive(b"\x00" + encode(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 1)))
    mcu.advance_to(mcu.next_tick_ns())  # SAMPLE 0
    for seq, counts in ((0, 16000), (1, 16000), (2, -16000)):
        mcu.receive(encode(Command(1, seq, counts, int(CommandFlags.ENABLE))))
        mcu.advance_to(mcu.next_tick_ns())  # applies it
        tim1 = mcu.tim1
        assert mcu.gpioa.output(7) == (counts > 0)
        if seq == 2:
            assert tim1.ccr1_active == 0, "the old duty drives the reversed bridge"
            assert tim1.regs[tim1.CCR1] == 16000 * 4200 // 32767
        mcu.advance_to(mcu.clock.now_ns + 100_000)  # two PWM periods: the preload is in force
        assert tim1.ccr1_active == 16000 * 4200 // 32767


def test_a_handler_that_never_returns_is_an_error_naming_it(image: Path) -> None:
    """An interrupt the image has no handler for lands in Default_Handler, which spins: the model says where the CPU
    is stuck instead of hanging."""
    from hil_mock.board_model.mcu import Stm32f401
    from hil_mock.board_model.peripherals import ModelError

    mcu = Stm32f401(image)
    mcu.reset()
    mcu.nvic_enabled[28] = True  # TIM2's line: board.c leaves it disabled and installs no handler
    mcu.raise_irq(28)
    with pytest.raises(ModelError, match=r"Default_Handler \(0x[0-9A-F]{8}\) still running after"):
        mcu.deliver()


def _streaming(image: Path, theta_code: int = 2048) -> tuple[object, StreamDecoder]:
    """The image on the model, a HELLO answered: the MCU about to make SAMPLE 0 at its next tick."""
    from hil_mock.board_model.mcu import Stm32f401

    mcu = Stm32f401(image)
    mcu.adc_code = lambda ch: theta_code
    mcu.reset()
    mcu.receive(b"\x00" + encode(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 1)))
    return mcu, StreamDecoder()


def _new_samples(mcu, dec: StreamDecoder) -> list[Sample]:  # type: ignore[no-untyped-def]
    out = [m for m in dec.feed(bytes(mcu.tx)) if isinstance(m, Sample)]
    mcu.tx.clear()
    return out


def test_a_rate_change_in_a_long_tick_never_stalls_the_tick(image: Path) -> None:
    """CONFIG 500 → 2000 Hz decoded in a tick that has already run 0.6 ms (longer than the new 0.5 ms period): TIM5's
    count is past the new ARR when it is written. Without ARR preload the counter runs on to its 32-bit wrap (51 s
    without a tick); with it the next tick comes at once and the ones after every 0.5 ms, each SAMPLE's t_us on the
    device's clock."""
    from firmware_protocol import Config

    mcu, dec = _streaming(image)
    mcu.advance_to(mcu.next_tick_ns())  # SAMPLE 0
    mcu.receive(encode(Config(2000, 20)))
    mcu.stall("hal_tick_rate", 600_000, times=1)
    t_config = mcu.next_tick_ns()
    mcu.advance_to(t_config)  # decodes the CONFIG, sets the rate, SAMPLE 1
    assert mcu.next_tick_ns() - mcu.clock.now_ns < 1_000, "the tick stalled after the rate change"
    ticks = []
    for _ in range(6):
        ticks.append(mcu.next_tick_ns())
        mcu.advance_to(ticks[-1])
    assert [b - a for a, b in itertools.pairwise(ticks)] == [500_000] * 5
    samples = _new_samples(mcu, dec)
    assert [s.seq for s in samples] == list(range(8))
    assert [b.t_us - a.t_us for a, b in itertools.pairwise(samples[2:])] == [500] * 5


def test_a_tick_that_overruns_is_counted_once(image: Path) -> None:
    """One tick runs 3 ms at 500 Hz: the update of the period it overran sets UIF and the NVIC pending bit. The
    handler reports that period skipped (TICK_OVERRUN); it must not also run again at once for it, or the device's
    clock counts the period twice. Every SAMPLE's t_us is the device time of its tick (one lost period, one
    TICK_OVERRUN)."""
    over = int(StatusFlags.TICK_OVERRUN)
    mcu, dec = _streaming(image)
    t0 = mcu.next_tick_ns()
    mcu.advance_to(t0)
    made = [(t0, s) for s in _new_samples(mcu, dec)]  # (device time of each SAMPLE's tick, the SAMPLE)
    mcu.stall("fw_tick", 3_000_000, times=1)
    while mcu.clock.now_ns < t0 + 20_000_000:
        t = mcu.next_tick_ns()
        mcu.advance_to(t)
        made += [(t, s) for s in _new_samples(mcu, dec)]
    times = [t for t, _ in made]
    assert len(set(times)) == len(times), "two SAMPLEs made by one timer update (the pending bit re-ran the tick)"
    t_first, s_first = made[0]
    for t, s in made:
        assert s.t_us - s_first.t_us == (t - t_first) // 1000, (s.seq, s.t_us, t)
    assert sum(bool(s.status & over) for _, s in made) == 1


def test_config_keeps_the_tick_within_the_hardware_watchdog_and_caps_the_hold(image: Path) -> None:
    """The tick is the IWDG's only refresh (50 ms nominal, 34.7 ms with the LSI at its fastest, 47 kHz): CONFIG
    refuses a rate below 50 Hz (at 20 Hz the board resets), and a watchdog_ms above 500 ms (a silent host would leave
    the motor driven that long; the protocol allows 65 s). 50 Hz with 500 ms is accepted, and with the fastest LSI the
    board runs 2 s at that rate without a reset."""
    from firmware_protocol import Config, Status

    rejected = int(StatusFlags.CONFIG_REJECTED)
    mcu, dec = _streaming(image)
    mcu.iwdg.lsi_hz = 47_000

    def configure(rate_hz: int, watchdog_ms: int) -> Status:
        mcu.receive(encode(Config(rate_hz, watchdog_ms)))
        mcu.advance_to(mcu.next_tick_ns())
        status = [m for m in dec.feed(bytes(mcu.tx)) if isinstance(m, Status)]
        mcu.tx.clear()
        return status[-1]

    for rate_hz, watchdog_ms in ((20, 20), (49, 20), (500, 501), (500, 65535)):
        st = configure(rate_hz, watchdog_ms)
        assert st.flags & rejected and (st.rate_hz, st.watchdog_ms) == (500, 20), (rate_hz, watchdog_ms)
    st = configure(50, 500)
    assert not st.flags & rejected and (st.rate_hz, st.watchdog_ms) == (50, 500)
    t = mcu.clock.now_ns
    mcu.advance_to(t + 2_000_000_000)
    assert (mcu.resets, mcu.watchdog_resets) == (1, 0)
    assert mcu.next_tick_ns() - mcu.clock.now_ns <= 20_000_000


@pytest.mark.hil
def test_a_watchdog_the_board_refuses_is_one_line_from_the_daemon(image: Path, tmp_path: Path) -> None:
    """`furuta-rt run --watchdog-ms 1000` against the board image: its CONFIG is refused (500 ms at most), and the
    daemon says so in one line naming both values and the options, without a traceback."""
    d = DaemonProcess(["--mock", "--mock-firmware", "board", "--config", "macstepien", "--duration", "1", "--no-tui",
                       "--watchdog-ms", "1000", LOCKSTEP, "--log", str(tmp_path / "run.mcap")])
    rc = d.wait(timeout=120)
    out = d.stderr + d.stdout
    assert rc not in (0, None) and traceback_free(out), out
    assert "the device rejected rate 500 Hz / watchdog 1000 ms (it runs at 500 Hz / 20 ms)" in out, out
    assert "--watchdog-ms" in out


def _driving(image: Path, counts: int):  # type: ignore[no-untyped-def]
    """The image streaming with COMMAND ``counts`` (ENABLE) applied: the bridge driven."""
    from firmware_protocol import Command, CommandFlags

    mcu, _ = _streaming(image)
    mcu.advance_to(mcu.next_tick_ns())  # SAMPLE 0
    for seq in (0, 1):
        mcu.receive(encode(Command(1, seq, counts, int(CommandFlags.ENABLE))))
        mcu.advance_to(mcu.next_tick_ns())
    mcu.advance_to(mcu.clock.now_ns + 100_000)  # the duty's preload in force
    mcu.tx.clear()
    return mcu


@pytest.mark.parametrize("cause", ["HardFault", "an interrupt without a handler"])
def test_a_fault_drives_the_pwm_low_before_it_spins(image: Path, cause: str) -> None:
    """The fault handler spins until the IWDG resets the board (34–94 ms with the LSI's spread): the bridge must not
    keep the last duty meanwhile. Driving +16000 (49 %), a HardFault — or an interrupt landing in the default handler
    — leaves PA8 low: no duty in force and none preloaded."""
    from hil_mock.board_model.device import bridge_duty
    from hil_mock.board_model.peripherals import ModelError

    mcu = _driving(image, 16000)
    assert bridge_duty(mcu) == pytest.approx(16000 * 4200 // 32767 / 4200)
    with pytest.raises(ModelError, match=r"Default_Handler \(0x[0-9A-F]{8}\) still running"):
        if cause == "HardFault":
            mcu.hard_fault()
        else:
            mcu.nvic_enabled[28] = True  # TIM2's line: board.c installs no handler
            mcu.raise_irq(28)
            mcu.deliver()
    assert bridge_duty(mcu) == 0.0 and bridge_duty(mcu, settled=True) == 0.0
    assert mcu.gpioa.mode(8) == 1 and not mcu.gpioa.output(8)  # the pin itself, whatever the timer does


def test_a_debugger_halt_takes_the_drive_off_and_holds_the_watchdog_and_the_tick(image: Path) -> None:
    """A debugger halts the core while it drives +16000: TIM1's output goes off (zero drive at the bridge), a second
    at the breakpoint does not let the IWDG reset the board, and the tick resumes where it stopped (the next SAMPLE
    one period on in the device's time, no TICK_OVERRUN)."""
    from hil_mock.board_model.device import bridge_duty

    mcu = _driving(image, 16000)
    dec = StreamDecoder()
    assert bridge_duty(mcu) > 0.4
    mcu.debug_halt()
    t = mcu.clock.now_ns
    mcu.advance_to(t + 100_000)
    assert bridge_duty(mcu) == 0.0, "the PWM runs on while the core is halted"
    mcu.advance_to(t + 1_000_000_000)
    assert bridge_duty(mcu) == 0.0 and (mcu.resets, mcu.watchdog_resets) == (1, 0)
    mcu.debug_resume()
    mcu.advance_to(mcu.next_tick_ns())
    mcu.advance_to(mcu.next_tick_ns())
    after = _new_samples(mcu, dec)
    assert [s.seq for s in after] == [3, 4] and after[1].t_us - after[0].t_us == 2000
    assert not any(s.status & StatusFlags.TICK_OVERRUN for s in after)


def test_theta_is_sampled_at_the_tick_and_phi_with_it(image: Path) -> None:
    """θ and the encoder ramp with device time (θ: µs past the millisecond as a 12-bit code, φ: µs). The tick's
    handler starts 30 µs late (a USART interrupt ahead of it) and decodes 300 µs of received bytes before fw_tick: θ
    must still be the value at the timer's update (TIM5 TRGO triggers the conversion), and φ latched at the handler's
    first instruction, not read inside fw_tick (a skew of 318 µs and more)."""
    from hil_mock.board_model.mcu import Stm32f401

    mcu = Stm32f401(image)
    mcu.adc_code = lambda ch: 2048 + (mcu.clock.now_ns // 1000) % 1000 if ch == 4 else 2048
    mcu.encoder = lambda: mcu.clock.now_ns // 1000
    mcu.reset()
    mcu.receive(b"\x00" + encode(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 1)))
    mcu.stall("TIM5_IRQHandler", 30_000)
    mcu.stall("fw_tick", 300_000)
    dec, made = StreamDecoder(), []
    for _ in range(4):
        t = mcu.next_tick_ns()
        mcu.advance_to(t)
        made += [(t // 1000, s) for s in _new_samples(mcu, dec)]
    assert len(made) == 4
    for t_us, s in made:
        assert s.theta_adc == t_us % 1000 == 0, f"θ sampled {s.theta_adc} µs after the tick"
        assert 0 <= s.phi_count - t_us <= 30, f"φ read {s.phi_count - t_us} µs after the tick"


def test_a_conversion_that_never_ends_is_a_fault_not_a_hang(image: Path) -> None:
    """The ADC's trigger lost (no conversion at the update): the tick waits a bounded time for it, then reports the
    rails, so ADC_OVERRANGE latches and the drive stays zero — the tick neither hangs nor sends a stale reading as
    a fresh one."""
    from hil_mock.board_model.device import bridge_duty

    mcu = _driving(image, 16000)
    assert bridge_duty(mcu) > 0.4
    mcu.adc.trigger = lambda jextsel: None  # type: ignore[method-assign]
    dec = StreamDecoder()
    mcu.advance_to(mcu.next_tick_ns())
    (s,) = _new_samples(mcu, dec)
    assert s.status & StatusFlags.ADC_OVERRANGE and (s.theta_adc, s.theta_dot_adc) == (-2048, -2048)
    assert bridge_duty(mcu, settled=True) == 0.0


def test_without_its_external_clock_the_board_runs_from_the_hsi(image: Path) -> None:
    """An HSE that never starts (a board without the ST-LINK's clock, a broken crystal): the image gives up after its
    bounded wait, turns it off and runs the PLL from the 16 MHz HSI — still 84 MHz, still a 500 Hz tick. With the
    wrong external clock fitted (25 MHz where the image expects 8), the model refuses the clock tree it makes."""
    from hil_mock.board_model.mcu import Stm32f401
    from hil_mock.board_model.peripherals import ModelError

    mcu = Stm32f401(image, hse_hz=None)
    mcu.reset()
    pll = mcu.rcc.read(mcu.rcc.PLLCFGR)
    assert not pll >> 22 & 1 and pll & 63 == 16 and not mcu.rcc.read(mcu.rcc.CR) >> 16 & 7
    assert mcu.next_tick_ns() == 2_000_000
    with pytest.raises(ModelError, match=r"PLL 25 MHz / M 8 × N 336 / P 4 = 262.5 MHz"):
        Stm32f401(image, hse_hz=25_000_000).reset()


@pytest.fixture(scope="module")
def encoder_image(image: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The image built with a pendulum encoder of 2048 counts per turn (the QUBE-Servo 2's) instead of the analog θ."""
    out = tmp_path_factory.mktemp("encoder-build")
    env = {**os.environ, "FURUTA_RT_BUILD_DIR": str(out), "BOARD_DEFINES": "-DBOARD_THETA_ENCODER_CPR=2048u"}
    res = subprocess.run([str(ROOT / "scripts" / "build_firmware")], capture_output=True, text=True, timeout=600,
                         check=False, env=env)
    assert res.returncode == 0, res.stderr
    return out / "stm32f401" / "furuta_fw.elf"


def test_a_pendulum_encoder_reports_theta_from_tim4(encoder_image: Path) -> None:
    """θ from a quadrature encoder on TIM4 (PB6/PB7): zero where the pendulum hung at power-up, so the reading is the
    count minus half a turn, wrapping at one turn (counts in [−1024, 1024) with 2048 per turn) and never over-range;
    HELLO_ACK reports 2π/2048 rad per count and offset 0. The analog θ on PA4 is not what the SAMPLE carries."""
    from hil_mock.board_model.mcu import Stm32f401

    mcu = Stm32f401(encoder_image)
    position = [0]
    mcu.theta_encoder = lambda: position[0]
    mcu.adc_code = lambda ch: 2048 + 700  # PA4's ADC code, unused: θ is the encoder's
    mcu.reset()
    mcu.receive(b"\x00" + encode(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 1)))
    moves = {0: -1024, 1024: 0, -1: 1023, 1: -1023, 1024 + 3 * 2048: 0, -5 * 2048 - 512: 512}
    for counts in moves:
        position[0] = counts
        mcu.advance_to(mcu.next_tick_ns())
    msgs = StreamDecoder().feed(bytes(mcu.tx))
    ack = msgs[0]
    assert isinstance(ack, HelloAck) and (ack.theta_offset_counts, ack.theta_rad_per_count) == (0, pytest.approx(
        2 * math.pi / 2048, rel=1e-6))
    samples = [m for m in msgs if isinstance(m, Sample)]
    assert [s.theta_adc for s in samples] == list(moves.values())
    assert not any(s.status & StatusFlags.ADC_OVERRANGE for s in samples)


def test_the_default_image_has_no_pendulum_encoder(image: Path) -> None:
    """The analog-θ image leaves TIM4 off: its θ is PA4's ADC reading."""
    samples = _samples_with(image, 2048 + 700, 2048, ticks=1)
    assert samples[0].theta_adc == 700


def test_the_uart_interrupt_load_is_priced_from_the_image(image: Path) -> None:
    """scripts/firmware_uart_load runs the image on the model and prices what it executes with firmware_ticks' model:
    one USART2 interrupt per byte received (a short straight path: 30–200 cycles with entry and exit), the tick's
    SAMPLE sent by DMA with no USART interrupt and one DMA interrupt at the transfer's end, and the load with 100
    bytes received per ms and a transfer a ms is 100 × received + the DMA interrupt."""
    res = subprocess.run([sys.executable, str(ROOT / "scripts" / "firmware_uart_load"), str(image)],
                         capture_output=True, text=True, timeout=120, check=False)
    assert res.returncode == 0, res.stderr
    m = re.search(r"interrupt (\d+) per byte received; bytes sent by DMA, (\d+) per transfer \((\d+) DMA interrupt\);"
                  r" .* in (\d+) USART interrupts\)\n.*: (\d+) cycles per ms", res.stdout)
    assert m, res.stdout
    rx, dma, dma_calls, usart_calls, load = (int(g) for g in m.groups())
    assert 30 <= rx <= 200 and 24 <= dma <= 200 and dma_calls == 1 and usart_calls == 0 and load == 100 * rx + dma


def test_frames_queued_while_the_line_is_busy_leave_when_the_transfer_ends(image: Path) -> None:
    """The UART sends by DMA, one transfer per tick. At 2 kHz the handshake tick's HELLO_ACK, STATUS and SAMPLE 0
    (106 bytes, 1.06 ms on the line) outlast two periods: the SAMPLEs of those ticks wait in the other buffer and
    leave in one transfer the moment the first ends (the stream's interrupt), not at a later tick; every frame
    arrives once, in order, with no TX_OVERFLOW."""
    mcu, dec = _streaming(image)
    mcu.receive(encode(Config(2000, 20)))
    mcu.advance_to(mcu.next_tick_ns())  # HELLO, CONFIG: HELLO_ACK + STATUS + SAMPLE 0 in one transfer
    first_end = mcu.dma.done_ns
    assert first_end is not None and mcu.dma.transfers == 1
    t0 = mcu.clock.now_ns
    assert first_end - t0 == 106 * 10_000  # 10 bits a byte at 1 Mbaud
    mcu.advance_to(t0 + 1_000_000)  # ticks at +0.5 and +1.0 ms: the line still busy
    assert mcu.dma.transfers == 1
    sent = len(mcu.tx)
    mcu.advance_to(first_end)  # the transfer ends: its interrupt starts the queued SAMPLEs 1 and 2
    assert mcu.dma.transfers == 2 and len(mcu.tx) == sent + 2 * 23
    mcu.advance_to(t0 + 10_000_000)
    msgs = dec.feed(bytes(mcu.tx))
    assert [type(m).__name__ for m in msgs[:3]] == ["HelloAck", "Status", "Sample"]
    samples = [m for m in msgs if isinstance(m, Sample)]
    assert [s.seq for s in samples] == list(range(len(samples))) and len(samples) == 21
    assert not any(s.status & StatusFlags.TX_OVERFLOW for s in samples)


def _word(mcu, symbol: str) -> int:  # type: ignore[no-untyped-def]
    return int.from_bytes(mcu.uc.mem_read(mcu.symbols[symbol], 4), "little")


def _hello_ack(mcu) -> HelloAck:  # type: ignore[no-untyped-def]
    """The image's answer to a HELLO now."""
    mcu.tx.clear()
    mcu.receive(b"\x00" + encode(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 5)))
    mcu.advance_to(mcu.next_tick_ns())
    ack = StreamDecoder().feed(bytes(mcu.tx))[0]
    assert isinstance(ack, HelloAck)
    return ack


def test_the_reset_cause_reaches_the_host(image: Path) -> None:
    """The image keeps RCC_CSR's reset flags of its start in `reset_flags` and clears them, so the next reset's are
    its own, and HELLO_ACK reports what they mean: power-on first (POR, PIN, BOR); then, the tick's interrupt masked
    (a hung tick), the IWDG resets the board within its 51 ms (IWDG, PIN: WATCHDOG); a HardFault, whose handler marks
    it in RAM start-up leaves alone and spins until the IWDG resets the board: FAULT; the reset button: PIN."""
    from firmware_protocol import ResetCause
    from hil_mock.board_model.peripherals import ModelError

    mcu, _ = _streaming(image)
    assert _word(mcu, "reset_flags") == 0x0E000000 and mcu.rcc.regs[mcu.rcc.CSR] & 0xFE000000 == 0
    assert _hello_ack(mcu).reset_cause == ResetCause.POWER_ON
    mcu.nvic_enabled[50] = False
    t = mcu.clock.now_ns
    mcu.advance_to(t + 60_000_000)
    assert mcu.watchdog_resets == 1 and _word(mcu, "reset_flags") == 0x24000000
    assert _hello_ack(mcu).reset_cause == ResetCause.WATCHDOG
    with pytest.raises(ModelError, match="Default_Handler"):
        mcu.hard_fault()
    mcu.advance_to(mcu.clock.now_ns + 100_000_000)  # the handler spins: the IWDG resets the board
    assert mcu.watchdog_resets == 2 and _word(mcu, "reset_flags") == 0x24000000
    assert _hello_ack(mcu).reset_cause == ResetCause.FAULT
    mcu.reset("pin")
    assert _hello_ack(mcu).reset_cause == ResetCause.PIN  # the fault's mark does not outlive the report


def test_uart_errors_are_counted_not_cleared_silently(image: Path) -> None:
    """A byte with a framing error, one with noise, and two bytes arriving before the first was read (an overrun):
    the USART interrupt counts them (`uart_line_errors` 2, `uart_overruns` 1) where it used to clear them unseen."""
    mcu, _ = _streaming(image)
    mcu.advance_to(mcu.next_tick_ns())  # the tick takes in the HELLO: STATUS counts from here
    assert (_word(mcu, "uart_line_errors"), _word(mcu, "uart_overruns")) == (0, 0)
    for errors in (1 << 1, 1 << 2):  # FE, NF
        mcu.usart.receive(0x55, errors)
        mcu.deliver()
    mcu.usart.receive(0x11)
    mcu.usart.receive(0x22)  # before the interrupt read 0x11: ORE
    mcu.deliver()
    assert (_word(mcu, "uart_line_errors"), _word(mcu, "uart_overruns")) == (2, 1)
    mcu.tx.clear()
    mcu.receive(b"\x00" + encode(Config(500, 20)))  # answered by a STATUS, which reports them to the host
    mcu.advance_to(mcu.next_tick_ns())
    status = next(m for m in StreamDecoder().feed(bytes(mcu.tx)) if isinstance(m, Status))
    assert (status.uart_line_errors, status.uart_overruns) == (2, 1)


def test_a_delayed_command_of_the_old_session_never_drives_the_board(image: Path) -> None:
    """The replay case on the flashed image: session 1 drives the bridge; a new HELLO (session 2) zeroes it; session
    1's COMMAND answering SAMPLE 0 with ENABLE, delayed past that HELLO, leaves PA8 low; session 2's own drives."""
    from firmware_protocol import Command, CommandFlags
    from hil_mock.board_model.device import bridge_duty

    mcu = _driving(image, 16000)  # session 1 (the HELLO's nonce 1)
    assert bridge_duty(mcu, settled=True) > 0.4
    mcu.receive(b"\x00" + encode(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 2)))
    mcu.advance_to(mcu.next_tick_ns())  # SAMPLE 0 of session 2, output zero
    mcu.receive(encode(Command(1, 0, 16000, int(CommandFlags.ENABLE))))
    for _ in range(3):
        mcu.advance_to(mcu.next_tick_ns())
        assert bridge_duty(mcu, settled=True) == 0.0
    samples = [m for m in StreamDecoder().feed(bytes(mcu.tx)) if isinstance(m, Sample)]
    assert samples[-1].seq == 3 and not samples[-1].status & StatusFlags.ENABLED
    mcu.receive(encode(Command(2, 3, 16000, int(CommandFlags.ENABLE))))
    mcu.advance_to(mcu.next_tick_ns())
    mcu.advance_to(mcu.clock.now_ns + 100_000)
    assert bridge_duty(mcu, settled=True) > 0.4


def test_no_stale_conversion_waits_for_the_next_tick(image: Path) -> None:
    """TIM5's UG (at start-up, and at a rate change inside a tick) is an update event, hence a TRGO and a conversion
    outside any tick's instant. Its JEOC must not be left set: on the silicon the next tick would take it for its own
    conversion's (which ends 6.5 µs after the update) and read that stale θ. After boot and after the CONFIG tick, no
    conversion is pending; the next tick's θ is the one at its update."""
    from firmware_protocol import Config

    mcu, dec = _streaming(image)
    jeoc = 1 << 2
    assert not mcu.adc.regs[mcu.adc.SR] & jeoc
    mcu.advance_to(mcu.next_tick_ns())
    mcu.receive(encode(Config(1000, 20)))
    mcu.adc_code = lambda ch: 2048 + 300 if ch == 4 else 2048  # θ moves after the CONFIG's conversion
    mcu.advance_to(mcu.next_tick_ns())  # the CONFIG tick: hal_tick_rate's UG converts
    assert not mcu.adc.regs[mcu.adc.SR] & jeoc, "a conversion of the rate change is left for the next tick"
    mcu.advance_to(mcu.next_tick_ns())
    assert _new_samples(mcu, dec)[-1].theta_adc == 300
