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
    """Writes ``pieces`` (wire bytes) to a raw pty one per ``period`` s and decodes what the host sends."""

    pieces: list[bytes]
    period: float = 0.002
    commands: list[fp.Command] = field(default_factory=list)
    other: list[fp.Message] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.fd, self.port = open_raw_pty()
        self.decoder = fp.StreamDecoder()
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
                (self.commands if isinstance(msg, fp.Command) else self.other).append(msg)

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


# ------------------------------------------------------------------ MCAP read-back
def mcap_counts_python_stream(path: str | Path) -> dict[str, Any]:
    """Messages per topic through mcap's Python StreamReader (tolerates a torn end)."""
    from mcap.stream_reader import StreamReader

    topics: dict[str, int] = {}
    channels: dict[int, str] = {}
    last: dict[str, int] = {}
    error = None
    complete = False
    with open(path, "rb") as fh:
        try:
            for rec in StreamReader(fh, skip_magic=False, emit_chunks=False).records:
                kind = type(rec).__name__
                if kind == "Channel":
                    channels[rec.id] = rec.topic
                elif kind == "Message":
                    topic = channels[rec.channel_id]
                    topics[topic] = topics.get(topic, 0) + 1
                    last[topic] = rec.log_time
                elif kind == "Footer":
                    complete = True
        except Exception as err:  # a torn file ends anywhere: McapError, EOFError, struct errors ...
            error = f"{type(err).__name__}: {err}"
    return {"reader": "python-mcap-stream", "complete": complete, "error": error, "topics": topics,
            "max_log_time": last}


NODE_SCRIPT = r"""
// Count messages per topic with @mcap/core's McapStreamReader (independent of the Python mcap package).
const fs = require("fs");
const { McapStreamReader } = require("@mcap/core");
const zstd = require("@foxglove/wasm-zstd");
const lz4 = require("@foxglove/wasm-lz4");
(async () => {
  await zstd.isLoaded;
  await lz4.isLoaded;
  const decompressHandlers = {
    zstd: (buf, size) => zstd.decompress(buf, Number(size)),
    lz4: (buf, size) => lz4(buf, Number(size)),
  };
  const reader = new McapStreamReader({ decompressHandlers });
  const data = fs.readFileSync(process.argv[2]);
  const channels = new Map();
  const topics = {};
  const last = {};
  let error = null;
  reader.append(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
  try {
    for (let rec; (rec = reader.nextRecord()); ) {
      if (rec.type === "Channel") channels.set(rec.id, rec.topic);
      else if (rec.type === "Message") {
        const topic = channels.get(rec.channelId);
        topics[topic] = (topics[topic] || 0) + 1;
        last[topic] = Number(rec.logTime);
      }
    }
  } catch (e) {
    error = String(e && e.message ? e.message : e);
  }
  console.log(JSON.stringify({ reader: "@mcap/core McapStreamReader", complete: reader.done(), error, topics,
                               max_log_time: last, bytes_left: reader.bytesRemaining() }));
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
        script = NPM_CACHE / "count_mcap.cjs"
        if not script.exists() or script.read_text() != NODE_SCRIPT:
            script.write_text(NODE_SCRIPT)
        return modules


def independent_mcap_counts(path: str | Path) -> dict[str, Any]:
    """Messages per topic by @mcap/core under node; falls back to mcap's Python StreamReader and says so
    in ``result["fallback"]`` (never returns without having read the file)."""
    modules = ensure_node_mcap()
    if modules is not None:
        proc = subprocess.run(["node", str(NPM_CACHE / "count_mcap.cjs"), str(path)], capture_output=True, text=True,
                              timeout=120, env={**os.environ, "NODE_PATH": str(modules)})
        if proc.returncode == 0 and proc.stdout.strip():
            out = json.loads(proc.stdout.strip().splitlines()[-1])
            out["fallback"] = ""
            return out
        reason = f"node failed ({proc.returncode}): {proc.stderr.strip()[:200]}"
    else:
        reason = "node/npm or @mcap/core unavailable"
    out = mcap_counts_python_stream(path)
    out["fallback"] = f"{reason}; used mcap's Python StreamReader instead"
    print(f"independent MCAP reader fallback: {out['fallback']}", file=sys.stderr)
    return out
