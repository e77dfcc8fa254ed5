"""Shared machinery of the reliability tests (tests/test_reliability*.py, tests/test_chaos*.py) and of
scripts/chaos: no tests here.

* ``load_fuzz_protocol()``: scripts/fuzz_protocol as a module (its stream generators, not a copy).
* ``PtyDevice``: a scripted device on a raw pty that writes given SAMPLE wire frames, paced, and
  decodes every COMMAND the host sends back (the host path under test is the daemon's own
  SerialHardware + ControlLoop).
* ``ListSink``: a queue stand-in collecting what the loop hands to its logger.
* ``mcap_summary()`` / ``node_mcap_summary()``: a log read back by our reader (furuta_rt.io.mcap_read)
  and by an independent one (@mcap/core's McapStreamReader under node, installed from npm into a
  cache directory; if npm is unavailable, mcap's Python StreamReader, and the result says so).
"""

from __future__ import annotations

import contextlib
import importlib.machinery
import importlib.util
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

import firmware_protocol as fp
from hil_mock.ptyport import open_raw_pty

ROOT = Path(__file__).resolve().parent.parent
NPM_CACHE = Path(os.environ.get("FURUTA_NPM_CACHE", ROOT / ".venv" / "npm-mcap"))
NPM_PACKAGES = ("@mcap/core@2", "@foxglove/wasm-zstd@1", "@foxglove/wasm-lz4@1")


def load_fuzz_protocol() -> ModuleType:
    """scripts/fuzz_protocol (a script without .py suffix) imported as a module."""
    path = ROOT / "scripts" / "fuzz_protocol"
    loader = importlib.machinery.SourceFileLoader("fuzz_protocol", str(path))
    spec = importlib.util.spec_from_loader("fuzz_protocol", loader)
    assert spec is not None
    mod = importlib.util.module_from_spec(spec)
    loader.exec_module(mod)
    return mod


class ListSink:
    """Stands in for the logger queue: keeps every item (never full)."""

    def __init__(self) -> None:
        self.items: list[Any] = []

    def put_nowait(self, item: Any) -> None:
        self.items.append(item)

    def ticks(self) -> list[tuple]:
        return [rec for kind, *rest in self.items if kind == "ticks" for rec in rest[0]]

    def events(self) -> list[str]:
        return [rest[0][2] for kind, *rest in self.items if kind == "event"]


@dataclass
class PtyDevice:
    """Writes ``pieces`` (wire bytes) to a raw pty one per ``period`` s and decodes what the host sends.
    COMMANDs are accepted by PROTOCOL.md §6 (firmware_protocol.command_accepted, the rule of hil_mock's
    firmware) against the SAMPLEs that left intact; a SAMPLE seq going back is a new session; STOP
    ends the session. ``acted`` lists what took effect, in order: ("command", Command) | ("stop", Stop)."""

    pieces: list[bytes]
    period: float = 0.002
    commands: list[fp.Command] = field(default_factory=list)
    accepted: list[bool] = field(default_factory=list)
    other: list[fp.Message] = field(default_factory=list)
    acted: list[tuple[str, fp.Message]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.fd, self.port = open_raw_pty()
        self.decoder = fp.StreamDecoder()
        self._sent = fp.StreamDecoder()  # what left the device intact
        self._last_sent: int | None = None
        self._last_accepted: int | None = None
        self._streaming = True
        self.done = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> PtyDevice:
        self._thread.start()
        return self

    def _drain(self) -> None:
        while True:
            try:
                data = os.read(self.fd, 4096)
            except (BlockingIOError, OSError):
                return
            if not data:
                return
            for msg in self.decoder.feed(data):
                if isinstance(msg, fp.Command):
                    ok = self._streaming and fp.command_accepted(msg.seq, self._last_sent, self._last_accepted)
                    self.commands.append(msg)
                    self.accepted.append(ok)
                    if ok:
                        self._last_accepted = msg.seq
                        self.acted.append(("command", msg))
                    continue
                self.other.append(msg)
                if isinstance(msg, fp.Stop):
                    self._streaming = False
                    self.acted.append(("stop", msg))

    def _note_sent(self, piece: bytes) -> None:
        for msg in self._sent.feed(piece):
            if isinstance(msg, fp.Sample):
                if self._last_sent is not None and fp.wrap_delta(msg.seq, self._last_sent) <= 0:
                    self._last_accepted = None  # seq went back: the device restarted its session
                self._last_sent = msg.seq

    @property
    def output_zero(self) -> bool:
        """The host's last frame that took effect zeroes the actuator (STOP, or u = 0 / ENABLE clear)."""
        if not self.acted:
            return True
        kind, msg = self.acted[-1]
        return kind == "stop" or (msg.command == 0 and not msg.flags & fp.CommandFlags.ENABLE)  # type: ignore[attr-defined]

    def _run(self) -> None:
        # wait until the host has the port open (reads stop failing with EIO)
        end = time.monotonic() + 10.0
        while time.monotonic() < end:
            try:
                os.read(self.fd, 4096)
                break
            except BlockingIOError:
                break
            except OSError:
                time.sleep(0.005)
        for piece in self.pieces:
            self._note_sent(piece)
            view = memoryview(piece)
            while view:
                try:
                    n = os.write(self.fd, view)
                except BlockingIOError:
                    time.sleep(0.0005)
                    continue
                view = view[n:]
            self._drain()
            time.sleep(self.period)
        self.done.set()

    def finish(self, linger: float = 0.3) -> None:
        """Wait for the writer, collect the host's last bytes, close the pty."""
        self._thread.join(60.0)
        time.sleep(linger)
        self._drain()
        with contextlib.suppress(OSError):
            os.close(self.fd)


def run_host_loop(pieces: list[bytes], *, link_timeout_s: float, rate: int = 500, duration: float | None = None,
                  first_sample_timeout: float = 10.0) -> tuple[Any, ListSink, PtyDevice, Any]:
    """The daemon's own host path in-process: SerialHardware + ControlLoop (thesis rig, its supervisor with
    the overrun limit lifted: a Python writer thread is not a clock) against a PtyDevice writing ``pieces``.
    Returns (LoopResult, the logger sink, the device with the COMMANDs it got, the hardware)."""
    from furuta_rt.config import load_rig
    from furuta_rt.controller.controller import Controller
    from furuta_rt.model.rig import calibration_from_config
    from furuta_rt.runtime.hardware import SerialHardware
    from furuta_rt.runtime.loop import ControlLoop, LoopSettings
    from furuta_rt.runtime.supervisor import Supervisor, SupervisorLimits

    rig = load_rig("thesis")
    dev = PtyDevice(pieces, period=1.0 / rate).start()
    hw = SerialHardware(dev.port)
    hw.open()
    sink = ListSink()
    lim = SupervisorLimits.from_config(rig.safety, rate)
    lim = SupervisorLimits(lim.theta_limit, lim.phi_limit, lim.arm_theta, 10**9, lim.settle_ticks)
    loop = ControlLoop(hw, Controller.from_rig(rig), Supervisor(lim),
                       LoopSettings(rate_hz=rate, link_timeout_s=link_timeout_s, first_sample_timeout=first_sample_timeout,
                                    duration=duration),
                       full_scale=rig.actuator.limit, calibration=calibration_from_config(rig), log=sink)
    try:
        result = loop.run()
    finally:
        hw.close()
        dev.finish()
    return result, sink, dev, hw


# ------------------------------------------------------------------ MCAP read-back
NODE_PRELUDE = r"""
const fs = require("fs");
const { McapStreamReader } = require("@mcap/core");
const zstd = require("@foxglove/wasm-zstd");
const lz4 = require("@foxglove/wasm-lz4");
// the result, then exit once it is written: the wasm modules may keep node's event loop alive (a CI run saw
// the complete result printed and node still running 120 s later)
const done = (text) => process.stdout.write(text + "\n", () => process.exit(0));
(async () => {
  await zstd.isLoaded;
  await lz4.isLoaded;
  const decompressHandlers = {
    zstd: (buf, size) => zstd.decompress(buf, Number(size)),
    lz4: (buf, size) => lz4(buf, Number(size)),
  };
  const reader = new McapStreamReader({ decompressHandlers });
  const data = fs.readFileSync(process.argv[2]);
"""
"""The start of both node scripts: @mcap/core's McapStreamReader with zstd/lz4, over the file argv[2]."""

NODE_SCRIPT = r"""
// Count messages per topic with @mcap/core's McapStreamReader (independent of the Python mcap package).
// tick_records: the records in the furuta_rt.tick_batch messages (record_size from the log's schema record).
""" + NODE_PRELUDE + r"""  const channels = new Map();
  const schemas = new Map();
  const topics = {};
  const last = {};
  let tick_records = 0;
  let error = null;
  reader.append(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
  try {
    for (let rec; (rec = reader.nextRecord()); ) {
      if (rec.type === "Schema") schemas.set(rec.id, rec);
      else if (rec.type === "Channel") channels.set(rec.id, rec);
      else if (rec.type === "Message") {
        const ch = channels.get(rec.channelId);
        topics[ch.topic] = (topics[ch.topic] || 0) + 1;
        last[ch.topic] = rec.logTime.toString();  // ns as text: a JS number would round it
        if (ch.messageEncoding === "furuta_rt.tick_batch") {
          const size = JSON.parse(new TextDecoder().decode(schemas.get(ch.schemaId).data)).record_size;
          tick_records += rec.data.byteLength / size;
        }
      }
    }
  } catch (e) {
    error = String(e && e.message ? e.message : e);
  }
  done(JSON.stringify({ reader: "@mcap/core McapStreamReader", complete: reader.done(), error, topics,
                        tick_records, max_log_time: last, bytes_left: reader.bytesRemaining() }));
})().catch((e) => { console.error(String(e)); process.exit(3); });
"""

NODE_TIMES_SCRIPT = r"""
// Every message's log_time, publish_time and JSON `timestamp` (ns as text), and the metadata, with @mcap/core;
// a furuta_rt.tick_batch message gives one row per packed record, decoded from the layout in its schema record
// (the record's time_ns as the stamp).
""" + NODE_PRELUDE + r"""  reader.append(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
  const channels = new Map();
  const schemas = new Map();
  const metadata = {};
  const messages = [];
  const text = new TextDecoder();
  const sizes = { int64: 8, float64: 8, bool: 1, uint8: 1 };
  for (let rec; (rec = reader.nextRecord()); ) {
    if (rec.type === "Schema") schemas.set(rec.id, rec);
    else if (rec.type === "Channel") channels.set(rec.id, rec);
    else if (rec.type === "Metadata") metadata[rec.name] = Object.fromEntries(rec.metadata);
    else if (rec.type === "Message" && channels.get(rec.channelId).messageEncoding === "furuta_rt.tick_batch") {
      const ch = channels.get(rec.channelId);
      const layout = JSON.parse(text.decode(schemas.get(ch.schemaId).data));
      const at = {};
      let size = 0;
      for (const f of layout.fields) { at[f.name] = size; size += sizes[f.type]; }
      if (size !== layout.record_size || rec.data.byteLength % size !== 0) throw new Error("bad tick_batch record");
      const view = new DataView(rec.data.buffer, rec.data.byteOffset, rec.data.byteLength);
      for (let o = 0; o < rec.data.byteLength; o += size) {
        messages.push([ch.topic, rec.logTime.toString(), rec.publishTime.toString(),
                       view.getBigInt64(o + at.time_ns, true).toString(), Number(view.getBigInt64(o + at.seq, true)),
                       view.getFloat64(o + at.t, true), null]);
      }
    }
    else if (rec.type === "Message") {
      const body = JSON.parse(text.decode(rec.data));
      const ts = body.timestamp;
      const stamp = ts ? (BigInt(ts.sec) * 1000000000n + BigInt(ts.nsec)).toString() : null;
      messages.push([channels.get(rec.channelId).topic, rec.logTime.toString(), rec.publishTime.toString(), stamp,
                     body.seq === undefined ? null : body.seq, body.t === undefined ? null : body.t,
                     body.message === undefined ? null : body.message]);
    }
  }
  done(JSON.stringify({ reader: "@mcap/core McapStreamReader", metadata, messages }));
})().catch((e) => { console.error(String(e)); process.exit(3); });
"""

_npm_lock = threading.Lock()


def ensure_node_mcap() -> Path | None:
    """node_modules with @mcap/core (installed once into NPM_CACHE via npm); None if node/npm are missing."""
    with _npm_lock:
        node, npm = shutil.which("node"), shutil.which("npm")
        if node is None:
            return None
        modules = NPM_CACHE / "node_modules"
        if not all((modules / p.rsplit("@", 1)[0]).is_dir() for p in NPM_PACKAGES):
            if npm is None:
                return None
            NPM_CACHE.mkdir(parents=True, exist_ok=True)
            pkg = NPM_CACHE / "package.json"
            if not pkg.exists():
                pkg.write_text('{"name": "furuta-mcap-check", "private": true}\n')
            proc = subprocess.run([npm, "install", "--no-audit", "--no-fund", "--silent", *NPM_PACKAGES],
                                  cwd=NPM_CACHE, capture_output=True, text=True, timeout=300)
            if proc.returncode != 0:
                return None
        for name, text in (("count_mcap.cjs", NODE_SCRIPT), ("times_mcap.cjs", NODE_TIMES_SCRIPT)):
            script = NPM_CACHE / name
            if not script.exists() or script.read_text() != text:
                script.write_text(text)
        return modules


INDEPENDENT_READER = "@mcap/core McapStreamReader"


def independent_mcap_counts(path: str | Path) -> dict[str, Any]:
    """Messages per topic by @mcap/core under node (JavaScript: shares no code with our reader, which is
    built on the Python mcap package). Raises if it cannot run: there is no quiet fallback to a reader
    that is not independent."""
    modules = ensure_node_mcap()
    if modules is None:
        raise RuntimeError(f"the independent MCAP reader ({INDEPENDENT_READER}) is unavailable: node/npm or "
                           f"@mcap/core could not be installed into {NPM_CACHE}")
    proc = subprocess.run(["node", str(NPM_CACHE / "count_mcap.cjs"), str(path)], capture_output=True, text=True,
                          timeout=120, env={**os.environ, "NODE_PATH": str(modules)})
    if proc.returncode != 0 or not proc.stdout.strip():
        raise RuntimeError(f"{INDEPENDENT_READER} failed on {path} ({proc.returncode}): {proc.stderr.strip()[:300]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def independent_mcap_times(path: str | Path) -> dict[str, Any]:
    """Every message's [topic, log_time, publish_time, JSON timestamp (ns), seq, t, message] (times as int) and
    the metadata, read by @mcap/core under node (raises if it cannot run, as independent_mcap_counts); a
    /furuta/tick_batch message gives a row per tick record, its time_ns in place of the timestamp, decoded in
    JavaScript from the record layout in the log's own schema record."""
    modules = ensure_node_mcap()
    if modules is None:
        raise RuntimeError(f"the independent MCAP reader ({INDEPENDENT_READER}) is unavailable (node/npm)")
    proc = subprocess.run(["node", str(NPM_CACHE / "times_mcap.cjs"), str(path)], capture_output=True, text=True,
                          timeout=120, env={**os.environ, "NODE_PATH": str(modules)})
    if proc.returncode != 0 or not proc.stdout.strip():
        raise RuntimeError(f"{INDEPENDENT_READER} failed on {path} ({proc.returncode}): {proc.stderr.strip()[:300]}")
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    out["messages"] = [[m[0], int(m[1]), int(m[2]), None if m[3] is None else int(m[3]), *m[4:]] for m in out["messages"]]
    return out


# ------------------------------------------------------------------ HIL: a recording mock + the real daemon
_SCRIPT = Path(sys.executable).parent / "furuta-rt"
_INLINE_CLI = "import sys; from furuta_rt.cli import main; sys.exit(main())"
FURUTA_RT = [str(_SCRIPT)] if _SCRIPT.exists() else [sys.executable, "-c", _INLINE_CLI]
"""How a user starts the CLI (the console script of this venv)."""
HIL_RATE = 500
LOCKSTEP = "--mock-arg=--pacing=lockstep"
"""`furuta-rt run --mock` with the device paced by the host's COMMANDs: the device's time, not the machine's load,
decides the ticks (for runs that assert behaviour, not real-time timing)."""
SAMPLE_WIRE_LEN = 23  # COBS(SAMPLE inner, 21 bytes) + delimiter
TEST_SAFETY = {"link_loss_periods": 250, "max_consecutive_overruns": 250}
"""Rig overrides of the HIL tests (0.5 s at 500 Hz). A shared 2-core box now and then delays pty traffic by
tens of ms (measured up to 86 ms: the tty layer's kernel workers are not real-time), which at the defaults
(2 periods, 5 late ticks, 20 ms device watchdog) trips runs that are meant to keep balancing. The fault
tests assert the trip *cause*; the faults trip regardless of these limits. scripts/chaos runs the defaults."""


def write_test_rig(directory: Path, **safety: Any) -> Path:
    """The thesis rig with TEST_SAFETY (and ``safety`` overrides) as a TOML file."""
    from furuta_rt.config import load_rig
    from furuta_rt.io.rig_toml import rig_to_toml

    rig = load_rig("thesis")
    rig = rig.model_copy(update={"safety": rig.safety.model_copy(update={**TEST_SAFETY, **safety})})
    path = directory / "rig_test.toml"
    path.write_text(rig_to_toml(rig))
    return path


class _Recorder:
    """Device-side record of a mock run: every COMMAND received, every output change, resets, hangups,
    handshakes, and which SAMPLE frames left the device intact or corrupted."""

    def __init__(self, device: Any) -> None:
        from hil_mock.firmware import Firmware

        self.device = device
        fw = device.firmware
        if type(fw) is not Firmware:  # the hooks below are the Python device's protocol code; the C core has none
            raise TypeError("the recorder needs hil-mock's Python device (--firmware python)")
        self.commands: list[tuple[int, int, int, int, int, int]] = []  # wall ns, dev ns, session, seq, counts, flags
        self.accepted: list[bool] = []  # per COMMAND: accepted by the firmware (PROTOCOL.md §6)
        self.stops: list[tuple[int, int]] = []  # wall ns, dev ns of each STOP received
        self.outputs: list[tuple[int, int, float]] = [(time.time_ns(), fw.clock_ns, fw.output)]  # wall ns, dev ns, u
        self.output_ticks: list[int] = [fw.seq]  # per output change: the first device tick (SAMPLE seq) it is in force
        in_tick = [False]
        self.events: list[tuple[int, int, str]] = []  # wall ns, dev ns, what
        self.samples_intact: list[tuple[int, int]] = []  # (session, seq) of SAMPLEs that left the link unharmed
        self.samples_damaged: list[tuple[int, int]] = []
        on_command, set_output, on_hello, on_stop = fw._on_command, fw._set_output, fw._on_hello, fw._on_stop
        reboot, hangup, skip = fw.reboot, fw.hangup, fw.skip

        def _on_command(msg: fp.Command, *args: Any, **kwargs: Any) -> Any:
            self.commands.append((time.time_ns(), fw.clock_ns, fw.handshakes, msg.seq, msg.command, msg.flags))
            discarded = fw.commands_discarded
            out = on_command(msg, *args, **kwargs)
            self.accepted.append(fw.commands_discarded == discarded)
            return out

        def _on_stop(*args: Any, **kwargs: Any) -> Any:
            self.stops.append((time.time_ns(), fw.clock_ns))
            return on_stop(*args, **kwargs)

        def _set_output(u: float, *args: Any, **kwargs: Any) -> Any:
            if u != fw.output:
                self.outputs.append((time.time_ns(), fw.clock_ns, u))
                # set at tick j (after SAMPLE j, seq already j + 1): in force from tick j; between ticks (STOP,
                # hang-up) with SAMPLE j the last sent: from tick j + 1 (and for the rest of period j)
                self.output_ticks.append(fw.seq - 1 if in_tick[0] else fw.seq)
            return set_output(u, *args, **kwargs)

        def _on_hello(*args: Any, **kwargs: Any) -> Any:
            out = on_hello(*args, **kwargs)
            self.events.append((time.time_ns(), fw.clock_ns, "hello"))
            return out

        def _reboot(*args: Any, **kwargs: Any) -> Any:
            self.events.append((time.time_ns(), fw.clock_ns, "reset"))
            return reboot(*args, **kwargs)

        def _hangup(*args: Any, **kwargs: Any) -> Any:
            self.events.append((time.time_ns(), fw.clock_ns, "hangup"))
            return hangup(*args, **kwargs)

        def _skip(periods: int, *args: Any, **kwargs: Any) -> Any:
            self.events.append((time.time_ns(), fw.clock_ns, f"skip {periods}"))
            return skip(periods, *args, **kwargs)

        fw._on_command, fw._set_output, fw._on_hello, fw._on_stop = _on_command, _set_output, _on_hello, _on_stop
        streaming_tick = fw._streaming_tick

        def _streaming_tick(*args: Any, **kwargs: Any) -> Any:
            in_tick[0] = True
            try:
                return streaming_tick(*args, **kwargs)
            finally:
                in_tick[0] = False

        fw.reboot, fw.hangup, fw.skip, fw._streaming_tick = _reboot, _hangup, _skip, _streaming_tick
        link = device.link
        tx = link.tx

        class _Link:
            """The device's LinkFaults, noting for each SAMPLE frame whether it passed unharmed."""

            def __getattr__(self, name: str) -> Any:
                return getattr(link, name)

            def __setattr__(self, name: str, value: Any) -> None:
                setattr(link, name, value)

            def tx(_link: Any, data: bytes) -> bytes:
                out = tx(data)
                if len(data) == SAMPLE_WIRE_LEN and data[1] == fp.MsgType.SAMPLE:
                    seq = fp.decode_frame(data[:-1]).seq  # type: ignore[union-attr]
                    (self.samples_intact if out == data else self.samples_damaged).append((fw.handshakes, seq))
                return out

        device.link = _Link()

    def as_dict(self) -> dict[str, Any]:
        return {"commands": self.commands, "accepted": self.accepted, "stops": self.stops,
                "outputs": self.outputs, "events": self.events,
                "samples_intact": self.samples_intact, "samples_damaged": self.samples_damaged,
                "stats": self.device.stats.as_dict()}


def recording_mock_main(argv: list[str]) -> int:
    """``python tests/test_reliability_harness.py mock RECORD.json [hil-mock args]``: hil-mock, unchanged,
    with a _Recorder on its device; the record is written when it exits."""
    import hil_mock.cli as cli
    from hil_mock.device import VirtualDevice

    record_path = Path(argv[0])
    recorders: list[_Recorder] = []

    class RecordingDevice(VirtualDevice):
        def __init__(self, config: Any = None) -> None:
            super().__init__(config)
            recorders.append(_Recorder(self))

    cli.VirtualDevice = RecordingDevice  # type: ignore[misc]
    # SIGHUP: the device vanishes (pty closed), like ``--fault disconnect@T`` but when the test says so
    signal.signal(signal.SIGHUP, lambda *_: recorders[0].device.disconnect() if recorders else None)
    args = argv[1:]
    if not any(a == "--firmware" or a.startswith("--firmware=") for a in args):
        args = ["--firmware", "python", *args]  # the recorder watches the Python device's protocol decisions
    try:
        return cli.main(args)
    finally:
        if recorders:
            tmp = record_path.with_suffix(".tmp")
            tmp.write_text(json.dumps(recorders[0].as_dict()))
            tmp.replace(record_path)


@dataclass
class MockRecord:
    commands: list[tuple[int, int, int, int, int, int]]
    accepted: list[bool]
    stops: list[tuple[int, int]]
    outputs: list[tuple[int, int, float]]
    events: list[tuple[int, int, str]]
    samples_intact: list[tuple[int, int]]
    samples_damaged: list[tuple[int, int]]
    stats: dict[str, Any]

    def output_at(self, wall_ns: int) -> float:
        """The device's actuator output at host wall time ``wall_ns``."""
        u = self.outputs[0][2]
        for t, _, v in self.outputs:
            if t > wall_ns:
                break
            u = v
        return u

    def commands_after(self, wall_ns: int) -> list[tuple[int, int, int, int, int, int]]:
        return [c for c in self.commands if c[0] > wall_ns]

    @property
    def final_output(self) -> float:
        return self.outputs[-1][2]

    @property
    def last_command(self) -> tuple[int, int, int, int, int, int]:
        return self.commands[-1]

    def end_problems(self) -> list[str]:
        """Empty if the actuator output is zero at the end and the host's last frame that took effect zeroes
        it: a STOP after the last accepted COMMAND, or an accepted COMMAND with u = 0 and ENABLE clear. A
        COMMAND the device discarded (PROTOCOL.md §6) counts for nothing."""
        out = []
        if self.final_output != 0.0:
            out.append(f"actuator ended at {self.final_output}")
        acted = [c for c, ok in zip(self.commands, self.accepted, strict=True) if ok]
        last = acted[-1] if acted else None
        if self.stops and (last is None or self.stops[-1][0] >= last[0]):
            return out
        if last is not None and (last[4] != 0 or last[5] & fp.CommandFlags.ENABLE):
            out.append(f"last COMMAND accepted counts={last[4]} flags={last[5]} and no STOP after it")
        return out

    def assert_ends_safe(self) -> None:
        problems = self.end_problems()
        assert not problems, "; ".join(problems)


class MockProcess:
    """The recording mock as a subprocess (real-time priority like hil-mock itself)."""

    def __init__(self, tmp: Path, args: list[str] = (), rate: int = HIL_RATE) -> None:
        self.record_path = tmp / "mock_record.json"
        self.stats_path = tmp / "mock_stats.json"
        cmd = [sys.executable, str(Path(__file__).resolve()), "mock", str(self.record_path), "--pty",
               "--rate", str(rate), "--stats-json", str(self.stats_path), *args]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line.startswith("hil-mock: serving on "):
            self.proc.kill()
            raise RuntimeError(f"recording mock did not start: {line!r} {self.proc.communicate()[1]}")
        self.port = line.split("serving on ", 1)[1].strip()
        self.stderr = ""

    def reset(self) -> None:
        """Reboot the device now (hil-mock's SIGUSR2)."""
        self.proc.send_signal(signal.SIGUSR2)

    def disconnect(self) -> None:
        """Close the pty now (the recording mock's SIGHUP)."""
        self.proc.send_signal(signal.SIGHUP)

    def stop(self, timeout: float = 20.0) -> MockRecord:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)  # hil-mock stops and prints its statistics
        try:
            _, self.stderr = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, self.stderr = self.proc.communicate()
        data = json.loads(self.record_path.read_text())
        return MockRecord(
            commands=[tuple(c) for c in data["commands"]], accepted=data["accepted"],
            stops=[tuple(t) for t in data["stops"]], outputs=[tuple(o) for o in data["outputs"]],
            events=[tuple(e) for e in data["events"]], samples_intact=[tuple(s) for s in data["samples_intact"]],
            samples_damaged=[tuple(s) for s in data["samples_damaged"]], stats=data["stats"],
        )


class DaemonProcess:
    """``furuta-rt run --port PTY`` as a user starts it, in its own session (process group), with its
    stderr lines collected as they come (so a test can act when the loop reaches a state)."""

    def __init__(self, args: list[str], env: dict[str, str] | None = None, preexec_fn: Any = None) -> None:
        self.args = [*FURUTA_RT, "run", *args]
        self.proc = subprocess.Popen(self.args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                                     start_new_session=True, env=env, preexec_fn=preexec_fn)
        self.lines: list[str] = []
        self._cond = threading.Condition()
        self.stdout = ""
        self._t_err = threading.Thread(target=self._pump_err, daemon=True)
        self._t_out = threading.Thread(target=self._pump_out, daemon=True)
        self._t_err.start()
        self._t_out.start()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def _pump_err(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            with self._cond:
                self.lines.append(line.rstrip("\n"))
                self._cond.notify_all()

    def _pump_out(self) -> None:
        assert self.proc.stdout is not None
        self.stdout = self.proc.stdout.read()

    def wait_for_line(self, needle: str, timeout: float = 60.0) -> str:
        """The first stderr line containing ``needle`` (raises TimeoutError with what was printed)."""
        end = time.monotonic() + timeout
        with self._cond:
            while True:
                for line in self.lines:
                    if needle in line:
                        return line
                left = end - time.monotonic()
                if left <= 0 or (self.proc.poll() is not None and not self._t_err.is_alive()):
                    raise TimeoutError(f"no {needle!r} on the daemon's stderr; it printed: {self.lines}")
                self._cond.wait(min(left, 0.2))

    def wait(self, timeout: float = 120.0) -> int:
        try:
            rc = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill_group(signal.SIGKILL)
            rc = self.proc.wait(10)
            raise
        finally:
            self._t_err.join(10)
            self._t_out.join(10)
        return rc

    @property
    def stderr(self) -> str:
        return "\n".join(self.lines)

    def kill_group(self, sig: int) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, sig)

    def children(self) -> list[int]:
        """pids of the daemon's child processes (logger, dashboard, mock)."""
        return children_of(self.pid)

    def spawned(self) -> list[int]:
        """pids of the daemon's own helper processes (logger, dashboard: started by multiprocessing), not the mock."""
        out = []
        for pid in self.children():
            with contextlib.suppress(OSError):
                if "multiprocessing.spawn" in Path(f"/proc/{pid}/cmdline").read_text():
                    out.append(pid)
        return out

    def run_queue_wait_s(self) -> float:
        """Seconds the daemon's threads and its logger's and dashboard's spent runnable but not running so far (the
        scheduler's run-queue wait): the time a loaded machine kept them from their work, summed (an upper bound of
        what it can have delayed). The difference of two readings covers the time between them."""
        return sum(run_queue_wait_s(pid) for pid in [self.pid, *self.spawned()])


def children_of(pid: int) -> list[int]:
    """pids of the child processes of ``pid`` (none once it is gone)."""
    try:
        text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    except OSError:
        return []
    return [int(p) for p in text.split()]


def run_queue_wait_s(pid: int, tid: int | None = None) -> float:
    """The run-queue wait of the threads of ``pid`` so far, or of its thread ``tid``, from
    /proc/PID/task/TID/schedstat (0 for a process already gone)."""
    total = 0
    for stat in Path(f"/proc/{pid}/task").glob(f"{'*' if tid is None else tid}/schedstat"):
        with contextlib.suppress(OSError, ValueError, IndexError):
            total += int(stat.read_text().split()[1])
    return total * 1e-9


def write_locked(path: Path) -> bool:
    """A process holds an exclusive flock on ``path`` (read from /proc/locks: taking a lock to find out could make a
    run's own non-blocking lock fail)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return False
    key = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    for line in Path("/proc/locks").read_text().splitlines():
        fields = line.split()
        if "FLOCK" in fields and "WRITE" in fields and key in fields:
            return True
    return False


def wait_until_locked(path: Path, timeout: float = 60.0) -> None:
    """Until a running furuta-rt holds the write lock of ``path`` (its logger takes it when it opens the file,
    after the handshake: a state line on stderr does not mean the logger got there)."""
    end = time.monotonic() + timeout
    while not write_locked(path):
        if time.monotonic() > end:
            raise TimeoutError(f"no run took the lock of {path} within {timeout:g} s")
        time.sleep(0.01)


def start_daemon(tmp: Path, port: str, *, duration: float | None, watchdog_ms: int = 500, log: bool = True,
                 extra: list[str] = (), rig: str | Path | None = None, **popen: Any) -> DaemonProcess:
    """``furuta-rt run --port PORT`` with the test rig, a log and a summary JSON in ``tmp``."""
    args = ["--port", port, "--config", str(rig or write_test_rig(tmp)), "--no-tui", "--watchdog-ms", str(watchdog_ms),
            "--summary-json", str(tmp / "summary.json")]
    if duration is not None:
        args += ["--duration", f"{duration:g}"]
    if log:
        args += ["--log", str(tmp / "run.mcap")]
    return DaemonProcess([*args, *extra], **popen)


def read_summary(tmp: Path) -> dict[str, Any]:
    return json.loads((tmp / "summary.json").read_text())


def traceback_free(text: str) -> bool:
    return "Traceback" not in text


# ------------------------------------------------------------------ running CLI cases as an unprivileged user
UNPRIVILEGED = 65534  # nobody/nogroup


def as_user_main(cases_json: str) -> int:
    """``python tests/test_reliability_harness.py asuser '{"name": [argv...]}'``: import the whole CLI as
    root (the interpreter may live under an unreadable /root), drop to uid/gid 65534, run each argv
    through ``furuta_rt.cli.main`` and print {"name": [exit code, stderr]} as one JSON line. Exceptions
    that escape main are reported as exit 99 with their traceback text."""
    import importlib
    import io
    import pkgutil
    import traceback
    from contextlib import redirect_stderr, redirect_stdout

    import serial
    import serial.serialposix  # noqa: F401

    import furuta_rt
    from furuta_rt.cli import build_parser, main

    for info in pkgutil.walk_packages(furuta_rt.__path__, "furuta_rt."):
        with contextlib.suppress(Exception):
            importlib.import_module(info.name)
    build_parser()
    os.setgroups([])
    os.setgid(UNPRIVILEGED)
    os.setuid(UNPRIVILEGED)
    os.environ["HOME"] = "/tmp"
    results: dict[str, Any] = {"__uid__": os.getuid()}
    for name, argv in json.loads(cases_json).items():
        err, out = io.StringIO(), io.StringIO()
        with redirect_stderr(err), redirect_stdout(out):
            try:
                rc = main(argv)
            except SystemExit as exc:
                rc = exc.code if isinstance(exc.code, int) else 1
            except BaseException:
                rc = 99
                err.write(traceback.format_exc())
        results[name] = [rc, err.getvalue()]
    print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    if len(sys.argv) > 1 and sys.argv[1] == "mock":
        raise SystemExit(recording_mock_main(sys.argv[2:]))
    if len(sys.argv) > 2 and sys.argv[1] == "asuser":
        raise SystemExit(as_user_main(sys.argv[2]))
    raise SystemExit("usage: test_reliability_harness.py mock RECORD.json [hil-mock args] | asuser CASES_JSON")
