"""The project's system packages, declared in scripts/system-packages.txt: list, install, and check a build's inputs.

    python3 scripts/system_packages.py list GROUP...            the packages of the groups, one a line
    python3 scripts/system_packages.py install LOG GROUP...     apt-get install the missing ones (root); exit 77 if it cannot
    python3 scripts/system_packages.py check LISTFILE GROUP...  every system file named in LISTFILE (one a line: the
                                                                headers and libraries a build read) belongs to a package
                                                                of the groups; exit 1 naming the first that does not

Standard library only: it runs before the project's virtual environment exists.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LIST = Path(__file__).resolve().parent / "system-packages.txt"
NAME = "system_packages"


def declared(path: Path = LIST) -> dict[str, str]:
    """package -> group, in the order of the list."""
    out: dict[str, str] = {}
    for n, raw in enumerate(path.read_text().splitlines(), 1):
        line = raw.split("#", 1)[0].split()
        if not line:
            continue
        if len(line) != 2:
            raise SystemExit(f"{NAME}: {path}:{n}: expected 'package group', got {raw.strip()!r}")
        out[line[0]] = line[1]
    return out


def packages(groups: list[str], path: Path = LIST) -> list[str]:
    table = declared(path)
    unknown = sorted(set(groups) - set(table.values()))
    if unknown:
        raise SystemExit(f"{NAME}: no group {', '.join(unknown)} in {path}")
    return [p for p, g in table.items() if g in groups]


def installed(package: str) -> bool:
    res = subprocess.run(["dpkg-query", "-W", "-f=${db:Status-Status}", package],
                         capture_output=True, text=True, check=False)
    return res.returncode == 0 and res.stdout.strip() == "installed"


def install(log: Path, groups: list[str], path: Path = LIST) -> int:
    """Install the groups' missing packages; 0 when all are there, 77 (one line why) when they cannot be."""
    if shutil.which("dpkg-query") is None:
        print(f"{NAME}: not a Debian/Ubuntu system (no dpkg); install {' '.join(packages(groups, path))} yourself",
              file=sys.stderr)
        return 77
    missing = [p for p in packages(groups, path) if not installed(p)]
    if not missing:
        return 0
    if os.geteuid() != 0 or shutil.which("apt-get") is None:
        print(f"{NAME}: {' '.join(missing)} not installed and cannot be installed here (needs root and apt-get)",
              file=sys.stderr)
        return 77
    print(f"{NAME}: installing {' '.join(missing)} (apt-get; log: {log})...", file=sys.stderr)
    log.parent.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    with log.open("w") as f:
        wait = ["-o", "DPkg::Lock::Timeout=600"]  # another clone's install may hold the lock: wait for it
        ok = subprocess.run(["apt-get", *wait, "update"], stdout=f, stderr=subprocess.STDOUT, env=env,
                            check=False).returncode == 0
        ok = ok and subprocess.run(["apt-get", *wait, "install", "-y", "-q", "--no-install-recommends", *missing],
                                   stdout=f, stderr=subprocess.STDOUT, env=env, check=False).returncode == 0
    still = [p for p in missing if not installed(p)]
    if not ok or still:
        print(f"{NAME}: apt-get could not install {' '.join(still or missing)} (see {log})", file=sys.stderr)
        return 77
    return 0


def owners(files: list[str]) -> dict[str, str | None]:
    """file -> the package that installed it (dpkg -S), None for a file no package owns."""
    out: dict[str, str | None] = {}
    for f in files:
        for candidate in dict.fromkeys((os.path.normpath(f), os.path.realpath(f))):
            res = subprocess.run(["dpkg-query", "-S", candidate], capture_output=True, text=True, check=False)
            if res.returncode == 0:
                # "pkg[:arch][, pkg2]: /path" (diversions start with "diversion by")
                names = [n.strip().split(":")[0] for n in res.stdout.splitlines()[0].rsplit(": ", 1)[0].split(",")]
                out[f] = names[0]
                break
        else:
            out[f] = None
    return out


def check(listfile: Path, groups: list[str], path: Path = LIST) -> int:
    """0 when every system file in ``listfile`` comes from a declared package of ``groups``; else 1, one line."""
    allowed = set(packages(groups, path))
    files = sorted({line.strip() for line in listfile.read_text().splitlines() if line.strip()})
    system = [f for f in files if not Path(os.path.realpath(f)).is_relative_to(ROOT)]
    if not system:
        print(f"{NAME}: {listfile} names no system file: the build's inputs were not recorded", file=sys.stderr)
        return 1
    found = owners(system)
    for f, pkg in found.items():
        if pkg not in allowed:
            where = f"package {pkg}" if pkg else "no package"
            print(f"{NAME}: the build used {f}, from {where}, which scripts/system-packages.txt does not declare for"
                  f" {'/'.join(groups)} ({', '.join(sorted(allowed))})", file=sys.stderr)
            return 1
    print(f"{NAME}: {len(system)} system headers and libraries, all from {', '.join(sorted({p for p in found.values() if p}))}")
    return 0


def main(argv: list[str]) -> int:
    if len(argv) >= 2 and argv[0] == "list":
        print("\n".join(packages(argv[1:])))
        return 0
    if len(argv) >= 3 and argv[0] == "install":
        return install(Path(argv[1]), argv[2:])
    if len(argv) >= 3 and argv[0] == "check":
        return check(Path(argv[1]), argv[2:])
    print(f"usage: {NAME}.py list GROUP... | install LOG GROUP... | check LISTFILE GROUP...", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
