"""The C99 firmware codec: strict gcc build, libc usage, and agreement with the Python codec.

The C test driver (firmware_protocol/c/test_vectors.c) reads the same golden-vector file
as the Python tests and checks encode/decode byte-for-byte, single-bit flips, invalid
frames and stream-decoder counters; it runs under AddressSanitizer/UBSan.
"""

from __future__ import annotations

import json
import random
import re
import shutil
import subprocess
from pathlib import Path

import pytest

import firmware_protocol as fp
from firmware_protocol import golden

C_DIR = Path(fp.__file__).parent / "c"
HEADER = C_DIR / "furuta_proto.h"
SOURCE = C_DIR / "furuta_proto.c"
DRIVER = C_DIR / "test_vectors.c"
GCC = shutil.which("gcc") or "gcc"
REQUIRED = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]
STRICT = [
    *REQUIRED,
    "-Wconversion",
    "-Wsign-conversion",
    "-Wshadow",
    "-Wstrict-prototypes",
    "-Wmissing-prototypes",
    "-Wcast-qual",
    "-Wcast-align",
]
SANITIZE = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-g", "-O1"]


def _gcc(args: list[str]) -> None:
    res = subprocess.run([GCC, *args], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, f"gcc {' '.join(args)}\n{res.stdout}{res.stderr}"


@pytest.fixture(scope="module")
def driver(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The C test driver built with the required flags and sanitizers."""
    out = tmp_path_factory.mktemp("c_codec") / "test_vectors"
    _gcc([*REQUIRED, *SANITIZE, f"-I{C_DIR}", str(SOURCE), str(DRIVER), "-o", str(out)])
    return out


def run_driver(driver: Path, vectors: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(driver), str(vectors), *extra], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("opt", ["-O0", "-O2", "-Os"])
def test_codec_builds_strictly_and_uses_no_libc_but_memcpy(tmp_path: Path, opt: str) -> None:
    obj = tmp_path / "furuta_proto.o"
    _gcc([*STRICT, opt, "-c", str(SOURCE), "-o", str(obj)])
    nm = subprocess.run(["nm", "-u", str(obj)], capture_output=True, text=True, check=True)
    undefined = {line.split()[-1] for line in nm.stdout.splitlines() if line.strip()}
    assert undefined <= {"memcpy"}, f"codec links against {undefined}"
    # freestanding (no hosted C library assumed), as on the microcontroller
    _gcc([*STRICT, opt, "-ffreestanding", "-c", str(SOURCE), "-o", str(tmp_path / "free.o")])


def test_codec_sources_include_only_allowed_headers() -> None:
    allowed = {"<stdint.h>", "<stddef.h>", "<string.h>", '"furuta_proto.h"'}
    for path in (HEADER, SOURCE):
        text = path.read_text()
        includes = set(re.findall(r"^\s*#\s*include\s+([<\"][^>\"]+[>\"])", text, re.M))
        assert includes <= allowed, f"{path.name}: {includes - allowed}"
        code = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
        for banned in ("malloc", "calloc", "realloc", "free(", "printf", "memmove", "memset"):
            assert banned not in code, f"{path.name} uses {banned}"


def _defines() -> dict[str, int]:
    out = {}
    pattern = r"^#define\s+(FP_\w+)\s+\(?(-?0x[0-9A-Fa-f]+|-?\d+)u?\)?\s*(?:/\*.*)?$"
    for name, value in re.findall(pattern, HEADER.read_text(), re.M):
        out[name] = int(value, 0)
    return out


def test_header_constants_match_python() -> None:
    d = _defines()
    assert d["FP_PROTOCOL_VERSION"] == fp.PROTOCOL_VERSION
    assert d["FP_SCHEMA_HASH"] == fp.SCHEMA_HASH, "update FP_SCHEMA_HASH in furuta_proto.h"
    assert d["FP_COMMAND_FULL_SCALE"] == fp.COMMAND_FULL_SCALE
    assert d["FP_DEFAULT_WATCHDOG_MS"] == fp.DEFAULT_WATCHDOG_MS
    for t in fp.MsgType:
        assert d[f"FP_MSG_{t.name}"] == t.value
        spec = fp.messages.SPECS[t.value]
        assert d[f"FP_BODY_{t.name}"] == spec.body_size
    for f in fp.StatusFlags:
        assert d[f"FP_ST_{f.name}"] == f.value
    for f in fp.CommandFlags:
        assert d[f"FP_CMD_{f.name}"] == f.value
    assert d["FP_ACT_TORQUE_NM"] == fp.ActuatorKind.TORQUE_NM
    assert d["FP_ACT_VOLTAGE_V"] == fp.ActuatorKind.VOLTAGE_V
    # error codes follow FrameStatus, negated
    for s in fp.FrameStatus:
        assert d[f"FP_ERR_{s.name}"] == -s.value


def test_c_codec_agrees_with_golden_vectors(driver: Path) -> None:
    res = run_driver(driver, golden.GOLDEN_PATH)
    assert res.returncode == 0, res.stdout + res.stderr
    doc = json.loads(golden.GOLDEN_PATH.read_text())
    kinds = [v["kind"] for v in doc["vectors"]]
    flips = sum(8 * len(v["frame"]) // 2 for v in doc["vectors"] if v["kind"] == "frame")
    types = ",".join(str(int(t)) for t in sorted(fp.MsgType))
    assert res.stdout.strip() == (
        f"ok frames={kinds.count('frame')} invalid={kinds.count('invalid')} streams={kinds.count('stream')} "
        f"cobs={kinds.count('cobs')} flips={flips} types={types}"
    )


def test_c_codec_agrees_on_random_messages_and_streams(driver: Path, tmp_path: Path) -> None:
    """Fresh seeded random vectors of every type (not only the golden ones), in the same format."""
    rng = random.Random(99)
    msgs = []
    for cls in fp.MESSAGE_CLASSES:
        for _ in range(60):
            vals: list[int | float] = []
            for code in cls.FORMAT:
                if code == "f":
                    vals.append(golden.f32(rng.choice((rng.uniform(-1e6, 1e6), rng.uniform(-1e-6, 1e-6)))))
                else:
                    lo, hi = golden._limits(code)
                    vals.append(rng.choice((lo, hi, 0, rng.randint(lo, hi), rng.randint(lo, hi))))
            msgs.append((f"rand_{cls.__name__}_{len(msgs)}", cls(*vals)))
    frames = [golden._frame_entry(name, m) for name, m in msgs]
    doc = {
        "format": "furuta-proto-golden/1",
        "protocol_version": fp.PROTOCOL_VERSION,
        "schema_hash": fp.SCHEMA_HASH,
        "counter_order": list(golden.COUNTER_ORDER),
        "vectors": frames + golden._stream_entries(frames),
    }
    path = tmp_path / "random.json"
    path.write_text(golden.dumps(doc))
    res = run_driver(driver, path)
    assert res.returncode == 0, res.stdout + res.stderr
    assert res.stdout.startswith(f"ok frames={len(frames)} invalid=0 streams=9 ")


def test_c_stream_decoder_fuzz_under_sanitizers(driver: Path) -> None:
    res = run_driver(driver, golden.GOLDEN_PATH, "3000000")
    assert res.returncode == 0, res.stdout + res.stderr
    m = re.search(r"clean_frames=(\d+) collisions=(\d+) frames_ok=(\d+)", res.stdout)
    assert m, res.stdout
    clean, collisions, ok = map(int, m.groups())
    assert clean > 50_000 and ok == clean + collisions


def _mutated(tmp_path: Path, old: str, new: str) -> Path:
    text = golden.GOLDEN_PATH.read_text()
    assert old in text
    path = tmp_path / "mutated.json"
    path.write_text(text.replace(old, new, 1))
    return path


def test_driver_detects_disagreement(driver: Path, tmp_path: Path) -> None:
    """The C check can fail: wrong frame byte, wrong value, wrong counter, wrong schema hash."""
    doc = json.loads(golden.GOLDEN_PATH.read_text())
    sample = next(v for v in doc["vectors"] if v["name"] == "sample_typical")
    stream = next(v for v in doc["vectors"] if v["kind"] == "stream" and v["name"] == "bit_flips")
    bad_frame = sample["frame"][:-2] + f"{int(sample['frame'][-2:], 16) ^ 1:02x}"
    cases = [
        (f'"frame": "{sample["frame"]}"', f'"frame": "{bad_frame}"', "fp_encode differs"),
        ('"values": [41, 41000, 2048', '"values": [41, 41001, 2048', "differs"),
        (
            f'"counters": {json.dumps(stream["counters"])}',
            f'"counters": {json.dumps([0] * 8)}',
            "counters differ",
        ),
        (f'"schema_hash": {fp.SCHEMA_HASH},', f'"schema_hash": {fp.SCHEMA_HASH ^ 1},', "FP_SCHEMA_HASH"),
        ('"error": "unknown_type"', '"error": "crc"', "wrong error code"),
    ]
    for old, new, message in cases:
        res = run_driver(driver, _mutated(tmp_path, old, new))
        assert res.returncode == 1, (old, res.stdout, res.stderr)
        assert message in res.stderr, (message, res.stderr)
