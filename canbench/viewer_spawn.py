"""The Rerun viewer `canbench view` opens (without --save): Rerun's own spawn, with the viewer's
gRPC server on loopback only (the rerun binary binds every interface unless told) and its usage
analytics off (the bench sends nothing beyond the machine). rerun.spawn can set neither, so it is
given a launcher that passes --bind 127.0.0.1 and a configuration directory of the bench's own in
which `rerun analytics disable` has been run (the user's own Rerun settings are left alone)."""
from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import rerun as rr

from .errors import InputError

HOME = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "canbench" / "rerun"


def rerun_binary() -> str:
    """The rerun command installed beside this Python (the venv's), else the one on PATH."""
    beside = Path(sys.executable).parent / "rerun"
    found = str(beside) if beside.is_file() else shutil.which("rerun")
    if found is None:
        raise InputError("rerun", None, "no rerun command beside this Python or on PATH (pip install rerun-sdk)")
    return found


def launcher(rerun: str, home: Path = HOME) -> Path:
    """A script that runs rerun with the arguments rerun.spawn gives it, on loopback, with the
    bench's configuration directory, analytics disabled in it once."""
    config = home / "config"
    if not (config / "rerun" / "analytics.json").is_file():
        subprocess.run([rerun, "analytics", "disable"], env={**os.environ, "XDG_CONFIG_HOME": str(config)},
                       check=True, capture_output=True, timeout=60)
    script = home / "rerun-loopback"
    script.write_text(f"#!/bin/sh\nXDG_CONFIG_HOME={shlex.quote(str(config))} exec {shlex.quote(rerun)} "
                      '--bind 127.0.0.1 "$@"\n')
    script.chmod(0o700)
    return script


def spawn_local_viewer() -> None:
    """rerun.spawn through the launcher: a viewer on 127.0.0.1:9876 that sends no usage data."""
    HOME.mkdir(parents=True, exist_ok=True)
    rr.spawn(executable_path=str(launcher(rerun_binary())))
