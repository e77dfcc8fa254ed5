"""``hil-mock --firmware board``: the flashed image on the board model, behind hil_mock's device loop.

``BoardFirmware`` is a drop-in for hil_mock.firmware.Firmware (the plant, its initial state and its replacement at a
new host session are inherited) whose protocol is made by ``furuta_fw.elf`` running on ``mcu.Stm32f401``. The plant
reaches the firmware only through the pins: θ and θ̇ as 12-bit ADC codes on PA4/PB0 (the board's calibration from
board_config.h, a full-turn θ sensor wrapping as the rig says), φ as TIM2's quadrature count, and the torque or
voltage on the plant is the PWM duty on PA8 (TIM1 CH1: CCR1 / (ARR + 1), zero with its main output off) signed by the
DIR pin PA7 times the board's full scale — zero whenever PA8 is not driven (the driver's pull-down), full while it is
a GPIO output set high. One ``tick`` lets device time run to TIM5's next update;
the device clock is the MCU's.

What the host sees is decoded from the wire only (the firmware's state stays inside the image): streaming, the
SAMPLE seq a COMMAND answers, and the counters of ``hil-mock``'s summary are those visible on the line.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

from firmware_protocol import Command, Config, Hello, ResetCause, Sample, Stop, StreamDecoder
from firmware_protocol.hostbuild import FIRMWARE_DIR, build_dir
from furuta_rt.config import RigConfig
from furuta_rt.model.rig import RigModel
from furuta_rt.model.sensors import Calibration, count_of
from hil_mock.board_model.mcu import Stm32f401
from hil_mock.board_model.peripherals import ModelError
from hil_mock.config import DeviceSettings
from hil_mock.firmware import Firmware

BOARD_CONFIG = FIRMWARE_DIR / "stm32f4" / "board_config.h"
THETA_CHANNEL, THETA_DOT_CHANNEL = 4, 8  # ADC1_IN4 = PA4, ADC1_IN8 = PB0
PIN_PWM, PIN_DIR = 8, 7  # PA8 = TIM1_CH1 (AF1), PA7 = direction
MODE_OUTPUT, MODE_AF, AF_TIM1 = 1, 2, 1
ADC_MID = 2048
_MCU_RESET = {ResetCause.POWER_ON: "power", ResetCause.PIN: "pin", ResetCause.WATCHDOG: "watchdog"}


def image_path() -> Path:
    """The image scripts/build_firmware makes (in the build directory)."""
    return build_dir() / "stm32f401" / "furuta_fw.elf"


def board_config() -> dict[str, float]:
    """The numeric ``#define BOARD_*`` values of board_config.h (what the image reports in HELLO_ACK)."""
    out = {}
    for m in re.finditer(r"#define (BOARD_\w+) \(?(-?[0-9.]+)[uf]?\)?", BOARD_CONFIG.read_text()):
        out[m.group(1)] = float(m.group(2))
    return out


def bridge_duty(mcu: Stm32f401, settled: bool = False) -> float:
    """The signed duty in [−1, 1] the H-bridge gets from PA8 (PWM) and PA7 (DIR, high = positive): the one in
    force, or ``settled``, the one from the next PWM period on (the preloads transferred, 50 µs later: what drives the
    plant over a tick)."""
    gpio = mcu.gpioa
    mode = gpio.mode(PIN_PWM)
    if mode == MODE_OUTPUT:
        duty = 1.0 if gpio.output(PIN_PWM) else 0.0
    elif mode == MODE_AF and gpio.alternate(PIN_PWM) == AF_TIM1:
        duty = mcu.tim1.oc1_duty(outputs_off=mcu.tim1_outputs_off(), settled=settled)
    else:
        duty = 0.0  # an input, analog or another function: the driver's pull-down holds it low
    positive = gpio.mode(PIN_DIR) == MODE_OUTPUT and gpio.output(PIN_DIR)
    return duty if positive or not duty else -duty


def board_calibration(rig: RigConfig) -> Calibration:
    cfg = board_config()
    return Calibration(theta_rad_per_count=cfg["BOARD_THETA_RAD_PER_COUNT"],
                       theta_offset_counts=int(cfg["BOARD_THETA_OFFSET_COUNTS"]),
                       theta_dot_rad_s_per_count=cfg["BOARD_THETA_DOT_RAD_S_PER_COUNT"],
                       phi_counts_per_rev=int(cfg["BOARD_PHI_COUNTS_PER_REV"]), adc_bits=12,
                       theta_wraps=rig.sensors.theta_wraps)


class BoardFirmware(Firmware):
    """hil_mock's device with the flashed image on the board model making every decision (module docstring)."""

    def __init__(self, rig: RigConfig, model: RigModel, settings: DeviceSettings, rate_hz: int,
                 image: Path | None = None) -> None:
        if rig.actuator.kind != "dc_motor":
            raise ValueError(f"the board image drives a voltage (H-bridge) actuator; rig '{rig.name}' is "
                             f"{rig.actuator.kind}-driven: give a dc_motor rig (e.g. --rig macstepien)")
        image = image or image_path()
        if not image.is_file():
            raise ValueError(f"no firmware image at {image}: run scripts/build_firmware first")
        model = dataclasses.replace(model, calibration=board_calibration(rig))
        super().__init__(rig, model, settings, rate_hz)
        self.full_scale = board_config()["BOARD_ACTUATOR_FULL_SCALE"]
        self.mcu = Stm32f401(image, hse_hz=int(board_config()["BOARD_HSE_HZ"]) or None)
        self.mcu.adc_code = self._adc_code
        self.mcu.encoder = self._encoder
        self._sampled: tuple[int, int] = (0, 0)
        self._rx = self.decoder = StreamDecoder()  # the host's frames as the line carries them
        self._txdec = StreamDecoder()
        self._pending = bytearray()
        self._last_sample: int | None = None
        self._hello_pending = False
        self._flags = 0
        self.mcu.reset()
        self._after()
        self.clock_ns = self._next_tick()
        self.period_ns = self.clock_ns
        self.rate_hz = round(1e9 / self.period_ns)

    # ------------------------------------------------------------ the pins
    def _adc_code(self, channel: int) -> int:
        if channel == THETA_CHANNEL:  # the injected sequence starts with θ: both are latched now
            raw = self.sim.sample()
            self._sampled = (raw.theta_adc - self.model.calibration.theta_offset_counts, raw.theta_dot_adc)
            return self._sampled[0] + ADC_MID
        if channel == THETA_DOT_CHANNEL:
            return self._sampled[1] + ADC_MID
        raise ModelError(f"board model: ADC1 channel {channel} converted, which has no sensor wired")

    def _encoder(self) -> int:
        return int(count_of(self.sim.phi, self.model.calibration.phi_rad_per_count))

    def _drive(self) -> float:
        """The actuator command the H-bridge makes of PA8 and PA7."""
        return bridge_duty(self.mcu, settled=True) * self.full_scale

    # ------------------------------------------------------------ after each run of the MCU
    def _after(self) -> None:
        """Frames out (split at their delimiters), what they say about the session, the actuator."""
        tx = self.mcu.tx
        if tx:
            self._pending += tx
            tx.clear()
            while (end := self._pending.find(0)) >= 0:
                frame = bytes(self._pending[:end + 1])
                del self._pending[:end + 1]
                self.tx.append(frame)
                for msg in self._txdec.feed(frame):
                    if type(msg) is Sample:
                        self._last_sample = msg.seq
                        self._flags = msg.status
                        self.samples_sent += 1
                        self.streaming = True
        self._set_output(self._drive())

    def _next_tick(self) -> int:
        t = self.mcu.next_tick_ns()
        if t is None:
            raise ModelError("board model: TIM5 (the tick) is not counting")
        return t

    # ------------------------------------------------------------ Firmware's interface
    @property
    def status_flags(self) -> int:
        return self._flags

    @property
    def armed(self) -> bool:
        return self.streaming and self.commands_applied > 0

    def receive(self, data: bytes) -> None:
        for msg in self._rx.feed(data):
            t = type(msg)
            if t is Command:
                self.commands_rx += 1
                if self.streaming and msg.seq == self._last_sample and msg.session == self.session:  # type: ignore[attr-defined]
                    self._answered = True
            elif t is Hello:
                self._reconfigured = True
                if self.plant_start_ns is None:
                    self.plant_start_ns = self.clock_ns
                elif not self.streaming:
                    self.sim = self._new_plant()
                    self.replacements += 1
                self.handshakes += 1
                self.streaming = True
                self.session = msg.nonce  # type: ignore[attr-defined]
                self._last_sample = None
            elif t is Stop:
                self.streaming = False
            elif t is Config:
                self._reconfigured = True
        self.mcu.receive(data)
        self._after()

    def tick(self, advance: bool = True) -> None:
        if self._answered:
            self.commands_applied += 1
        self._answered = self._reconfigured = False
        now = self.clock_ns
        self.mcu.advance_to(now)
        self._after()
        self.clock_ns = self._next_tick()
        self.period_ns = self.clock_ns - now
        self.rate_hz = round(1e9 / self.period_ns)
        if advance:
            self.advance_plant()

    def skip(self, periods: int) -> None:
        """The simulation fell behind wall time: the board is paused for those periods (its clocks held, as a debugger
        halt with the timers frozen) while the plant runs on with the output held; no SAMPLE is made."""
        if periods > 0:
            dt = periods * self.period_ns
            self.mcu.pause(dt)
            self.clock_ns += dt
            self.advance_plant()

    def reboot(self, cause: ResetCause = ResetCause.PIN) -> None:
        """A reset of the board for ``cause`` (its RCC_CSR flags set as the hardware sets them)."""
        self.tx.clear()
        self.reboots += 1
        self.reset_cause = cause
        self.streaming = False
        if cause not in _MCU_RESET:
            raise ValueError(f"the board model resets by {', '.join(c.name for c in _MCU_RESET)}, not {cause.name}")
        self.mcu.reset(_MCU_RESET[cause])
        self._after()
        self.clock_ns = self._next_tick()

    def hangup(self) -> None:
        """A UART has no DTR: the board does not see the host go (its watchdog does)."""

    def note_tx_overflow(self) -> None:
        """The board cannot know the host did not read: nothing to note."""
