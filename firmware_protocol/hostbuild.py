"""The DAQ firmware core (firmware/core, firmware/host) built for this machine as a shared library.

hil_mock loads it to run the C firmware as its device logic (``hil-mock --firmware c``). The library is
built once per source/compiler combination with the system C compiler and cached in ``$FURUTA_RT_BUILD_DIR``,
else in the clone's ``build/`` (a source checkout), else in ``$XDG_CACHE_HOME/furuta-rt`` (an installed package):
a build never writes into another clone's folder.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

PACKAGE_DIR = Path(__file__).parent
FIRMWARE_DIR = PACKAGE_DIR / "firmware"
CODEC_DIR = PACKAGE_DIR / "c"
CORE_DIR = FIRMWARE_DIR / "core"
SOURCES = (CORE_DIR / "fw_core.c", FIRMWARE_DIR / "host" / "host_hal.c", CODEC_DIR / "furuta_proto.c")
HEADERS = (CORE_DIR / "fw_core.h", CORE_DIR / "fw_hal.h", CODEC_DIR / "furuta_proto.h")
REQUIRED_FLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic")
HOST_FLAGS = (*REQUIRED_FLAGS, "-O2", "-fPIC", "-shared", f"-I{CORE_DIR}", f"-I{CODEC_DIR}")
LIBRARY_NAME = "libfuruta_fw"


class BuildError(RuntimeError):
    """The host build of the firmware failed; the message is one line naming the cause."""


def build_dir() -> Path:
    """Where firmware builds go: ``$FURUTA_RT_BUILD_DIR``, the clone's ``build/``, or the user's cache."""
    explicit = os.environ.get("FURUTA_RT_BUILD_DIR")
    if explicit:
        return Path(explicit)
    checkout = PACKAGE_DIR.parent
    if (checkout / "pyproject.toml").is_file() and os.access(checkout, os.W_OK):
        return checkout / "build"
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(cache) / "furuta-rt"


def _compiler() -> str:
    explicit = os.environ.get("CC")
    if explicit:
        found = shutil.which(explicit)
        if not found:
            raise BuildError(f"CC={explicit}: no such compiler, needed to build the C firmware for the host")
        return found
    cc = shutil.which("gcc") or shutil.which("cc")
    if not cc:
        raise BuildError("no C compiler found (install gcc, or set CC) to build the C firmware for the host")
    return cc


def _key(cc: str, files: tuple[Path, ...], flags: tuple[str, ...]) -> str:
    h = hashlib.sha256()
    version = subprocess.run([cc, "--version"], capture_output=True, text=True, check=False).stdout
    for part in (cc, version, *flags):
        h.update(part.encode())
    for path in files:
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def host_library(sources: tuple[Path, ...] = SOURCES, headers: tuple[Path, ...] = HEADERS,
                 name: str = LIBRARY_NAME, libs: tuple[str, ...] = (), include_dirs: tuple[Path, ...] = ()) -> Path:
    """A shared library built with the host's compiler and the firmware's flags, cached by source and compiler;
    by default the firmware core with the host HAL (the compiled plant and hil_mock's device pass their own)."""
    cc = _compiler()
    compile_flags = (*HOST_FLAGS, *(f"-I{d}" for d in include_dirs))
    out = build_dir() / f"{name}-{_key(cc, (*sources, *headers), (*compile_flags, *libs))}.so"
    if out.exists():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{name}-", suffix=".so", dir=out.parent)
    os.close(fd)
    try:
        res = subprocess.run([cc, *compile_flags, *map(str, sources), "-o", tmp, *libs], capture_output=True, text=True,
                             timeout=120, check=False)
        if res.returncode != 0:
            first = (res.stderr.strip().splitlines() or ["(no output)"])[0]
            raise BuildError(f"building {name} for the host failed: {first}")
        os.replace(tmp, out)  # atomic: concurrent builders agree on the result
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return out
