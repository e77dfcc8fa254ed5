"""The one list of system packages (scripts/system-packages.txt) and the check that a build read nothing else."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from scripts import system_packages as sp

ROOT = Path(__file__).resolve().parent.parent
needs_dpkg = pytest.mark.skipif(shutil.which("dpkg-query") is None, reason="not a Debian/Ubuntu system (no dpkg)")


def test_every_apt_get_install_in_the_scripts_reads_the_list() -> None:
    table = sp.declared()
    assert {"gcc-arm-none-eabi", "picolibc-arm-none-eabi", "qemu-system-arm"} == set(sp.packages(["firmware"]))
    assert table["chromium"] == "report"
    for script in (ROOT / "scripts").iterdir():
        if script.is_file() and script.name != "system_packages.py":
            assert "apt-get install" not in script.read_text(errors="replace"), script.name


def test_a_malformed_line_or_an_unknown_group_is_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "list.txt"
    bad.write_text("gcc-arm-none-eabi firmware\nchromium\n")
    with pytest.raises(SystemExit, match=r"list.txt:2: expected 'package group'"):
        sp.declared(bad)
    with pytest.raises(SystemExit, match="no group nosuch"):
        sp.packages(["nosuch"])


@needs_dpkg
def test_a_header_from_an_undeclared_package_fails_the_check(tmp_path: Path, capsys) -> None:
    # libc6-dev's string.h stands for a header of a C library the firmware group does not name (newlib's, say)
    header = Path("/usr/include/string.h")
    if not header.exists():
        pytest.skip("libc6-dev is not installed")
    listing = tmp_path / "inputs.txt"
    listing.write_text(f"{header}\n")
    assert sp.check(listing, ["firmware"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "/usr/include/string.h, from package libc6-dev" in err
    assert sp.check(listing, ["host"]) == 0  # declared for the host build


@needs_dpkg
def test_a_file_no_package_owns_or_an_empty_record_fails(tmp_path: Path, capsys) -> None:
    stray = tmp_path / "stray.h"
    stray.write_text("")
    listing = tmp_path / "inputs.txt"
    listing.write_text(f"{stray}\n")
    assert sp.check(listing, ["firmware"]) == 1
    assert "from no package" in capsys.readouterr().err
    listing.write_text(f"{ROOT / 'firmware_protocol/c/furuta_proto.h'}\n")  # only the clone's own files
    assert sp.check(listing, ["firmware"]) == 1
    assert "names no system file" in capsys.readouterr().err


@needs_dpkg
def test_install_without_root_names_the_missing_packages_and_exits_77(tmp_path: Path, monkeypatch, capsys) -> None:
    listing = tmp_path / "list.txt"
    listing.write_text("no-such-package-furuta-rt  extra\n")
    monkeypatch.setattr(sp.os, "geteuid", lambda: 1000)
    assert sp.install(tmp_path / "apt.log", ["extra"], listing) == 77
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no-such-package-furuta-rt not installed" in err[0] and "needs root" in err[0]


def test_the_readme_quick_start_is_two_commands() -> None:
    readme = (ROOT / "README.md").read_text()
    block = re.search(r"## Quick start\n.*?```sh\n(.*?)```", readme, re.S)
    assert block is not None
    commands = [line.split("#")[0].strip() for line in block.group(1).splitlines() if line.split("#")[0].strip()]
    assert commands == ["scripts/demo", "scripts/test"]
