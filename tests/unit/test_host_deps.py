"""scripts/host-deps, how make check and make base install what they need: only the missing
Debian packages, with apt-get as root or through passwordless sudo, else one command to run
(dpkg-query, apt-get, sudo and id replaced by stand-ins that record what they are asked)."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "host-deps"

STANDINS = {
    # installed: the packages listed in $INSTALLED
    "dpkg-query": 'for p in $INSTALLED; do [ "$p" = "${@: -1}" ] && { echo "install ok installed"; exit 0; }; done\n'
                  'exit 1',
    "apt-get": 'echo "apt-get $*" >>"$CALLS"',
    "sudo": '[ "$1" = -n ] && shift; [ -n "$SUDO_OK" ] || exit 1; [ "$1" = true ] && exit 0; echo "sudo $*" >>"$CALLS"',
    "id": 'echo "${FAKE_UID:-0}"',
}


@pytest.fixture
def host(tmp_path):
    bins = tmp_path / "bin"
    bins.mkdir()
    for name, body in STANDINS.items():
        (bins / name).write_text(f"#!/usr/bin/env bash\n{body}\n")
        (bins / name).chmod(0o755)
    calls = tmp_path / "calls"

    def run(*packages: str, **env: str) -> tuple[subprocess.CompletedProcess, list[str]]:
        proc = subprocess.run([str(SCRIPT), "make check", *packages], capture_output=True, text=True, timeout=30,
                              env={**os.environ, "PATH": f"{bins}:{os.environ['PATH']}", "CALLS": str(calls), **env})
        return proc, calls.read_text().splitlines() if calls.exists() else []

    return run


def test_nothing_missing_installs_nothing(host):
    proc, calls = host("cmake", "clang", INSTALLED="cmake clang")
    assert proc.returncode == 0 and calls == []


def test_root_installs_only_what_is_missing(host):
    proc, calls = host("cmake", "clang", "cpio", INSTALLED="clang")
    assert proc.returncode == 0, proc.stderr
    assert calls == ["apt-get update -qq", "apt-get install -y -qq cmake cpio"]


def test_passwordless_sudo_is_used(host):
    proc, calls = host("cmake", INSTALLED="", FAKE_UID="1000", SUDO_OK="1")
    assert proc.returncode == 0, proc.stderr
    assert calls == ["sudo env DEBIAN_FRONTEND=noninteractive apt-get update -qq",
                     "sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq cmake"]


def test_without_root_or_sudo_it_names_the_one_command(host):
    proc, calls = host("cmake", "cpio", INSTALLED="", FAKE_UID="1000")
    assert proc.returncode == 1 and calls == []
    assert "run: sudo apt-get install -y cmake cpio" in proc.stderr
