"""scripts/build-images schedules image builds by what each is built from: the
Python environment (pyenv) builds while the builder does, nothing starts before
the images it copies from exist, at most BUILD_PARALLEL run at once, an image
already built for the tag is not rebuilt, and a failed build stops the run with
its log's tail. Run against a stand-in `docker` on PATH that logs each build's
start and end; a build that must overlap another waits for it (bounded), so
the order is proven, not timed."""

from __future__ import annotations

import os
import shutil
import subprocess
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.unit

# docker image inspect: built when $STATE/<name> exists. docker build: logs start and end,
# and, for the image named in $WAIT_FOR_START_OF_<image>, waits (at most 10 s) until that
# other image's build has started: the builder must not end before pyenv starts.
FAKE_DOCKER = textwrap.dedent(
    """\
    #!/usr/bin/env bash
    set -u
    if [ "$1" = image ] && [ "$2" = inspect ]; then
        name=${3#canbench/}; name=${name%%:*}
        [ -e "$STATE/$name" ]; exit
    fi
    [ "$1" = build ] || exit 3
    file=$3; img=${file#images/}; img=${img%%/Dockerfile}
    echo "start $img" >>"$STATE/events"
    var=WAIT_FOR_START_OF_$img
    if [ -n "${!var:-}" ]; then
        for _ in $(seq 1000); do grep -q "^start ${!var}$" "$STATE/events" && break; sleep 0.01; done
    fi
    case " ${FAIL:-} " in *" $img "*) echo "step failed in $img"; echo "end $img" >>"$STATE/events"; exit 1;; esac
    touch "$STATE/$img"
    echo "end $img" >>"$STATE/events"
    """
)


def run(tmp_path: Path, *images: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    (tmp_path / "scripts").mkdir(exist_ok=True)
    shutil.copy(REPO / "scripts" / "build-images", tmp_path / "scripts" / "build-images")
    bindir = tmp_path / "bin"
    bindir.mkdir(exist_ok=True)
    (bindir / "docker").write_text(FAKE_DOCKER)
    (bindir / "docker").chmod(0o755)
    state = tmp_path / "state"
    state.mkdir(exist_ok=True)
    full_env = {
        **os.environ,
        "PATH": f"{bindir}:{os.environ['PATH']}",
        "STATE": str(state),
        "CACHE": str(tmp_path / "cache"),
        **(env or {}),
    }
    return subprocess.run(
        ["bash", str(tmp_path / "scripts" / "build-images"), "t1", "base:x", *images],
        env=full_env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def events(tmp_path: Path) -> list[tuple[str, str]]:
    lines = (tmp_path / "state" / "events").read_text().split()
    return list(zip(lines[::2], lines[1::2], strict=True))


def test_pyenv_builds_beside_the_builder_and_nothing_starts_before_what_it_copies_from(tmp_path: Path) -> None:
    # each waits for the other to start: on a loaded machine pyenv's stand-in could otherwise start
    # and end before the builder's had started, and the two would not be seen side by side
    done = run(tmp_path, env={"WAIT_FOR_START_OF_builder": "pyenv", "WAIT_FOR_START_OF_pyenv": "builder"})
    assert done.returncode == 0, done.stderr
    ev = events(tmp_path)
    at = {e: i for i, e in enumerate(ev)}
    assert at[("start", "pyenv")] < at[("end", "builder")], ev  # beside the builder
    for img, deps in {
        "router": ["builder"],
        "bus": ["builder"],
        "bridge": ["builder"],
        "ecu": ["builder", "pyenv"],
        "orchestrator": ["ecu"],
    }.items():
        for dep in deps:
            assert at[("end", dep)] < at[("start", img)], (img, dep, ev)
    running = peak = 0
    for kind, _ in ev:
        running += 1 if kind == "start" else -1
        peak = max(peak, running)
    assert peak == 2, ev  # BUILD_PARALLEL's default
    assert "built in" in done.stdout


def test_one_at_a_time_when_asked(tmp_path: Path) -> None:
    done = run(tmp_path, env={"BUILD_PARALLEL": "1"})
    assert done.returncode == 0, done.stderr
    ev = events(tmp_path)
    assert all(ev[i][0] == "start" and ev[i + 1] == ("end", ev[i][1]) for i in range(0, len(ev), 2)), ev


def test_an_image_built_for_the_tag_is_not_rebuilt(tmp_path: Path) -> None:
    (tmp_path / "state").mkdir()
    for img in ("builder", "pyenv"):
        (tmp_path / "state" / img).touch()
    done = run(tmp_path)
    assert done.returncode == 0, done.stderr
    started = [img for kind, img in events(tmp_path) if kind == "start"]
    assert "builder" not in started and "pyenv" not in started
    assert "canbench/builder:t1 up to date" in done.stdout


def test_a_failed_build_stops_the_run_with_its_log(tmp_path: Path) -> None:
    done = run(tmp_path, env={"FAIL": "pyenv"})
    assert done.returncode == 1
    assert "step failed in pyenv" in done.stderr
    assert "building canbench/pyenv failed" in done.stderr
    started = [img for kind, img in events(tmp_path) if kind == "start"]
    assert "ecu" not in started and "orchestrator" not in started


def test_an_image_whose_sources_are_missing_is_named(tmp_path: Path) -> None:
    done = run(tmp_path, "bench")  # bench is built from the builder and orchestrator: neither exists
    assert done.returncode == 1
    assert "cannot build bench" in done.stderr
