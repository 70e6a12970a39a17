"""The thread dump a failing bridge test records (tests/conftest.py: thread_dump and the
pytest_runtest_makereport hook): every thread of the live bridge with the syscall it sleeps in,
and its stack where gdb is installed; only for a failed test whose bridge still runs."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import thread_dump, wait_for

pytestmark = pytest.mark.unit
pytest_plugins = ["pytester"]

CONFTEST = Path(__file__).resolve().parents[1] / "conftest.py"
SLEEPER = [sys.executable, "-c", "import threading, time\n"
           "threading.Thread(target=time.sleep, args=(60,), name='sleeper', daemon=True).start()\n"
           "print('ready', flush=True)\ntime.sleep(60)"]


@pytest.fixture
def sleeper():
    proc = subprocess.Popen(SLEEPER, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"  # both threads started
    # the main thread prints before it sleeps: on a loaded machine it may not be asleep yet
    wait_for(lambda: all(_asleep(task) for task in Path(f"/proc/{proc.pid}/task").iterdir()),
             "the sleeper's threads asleep", timeout=10)
    yield proc
    proc.kill()
    proc.wait()


def _asleep(task: Path) -> bool:
    try:
        return (task / "stat").read_text().rsplit(")", 1)[1].split()[0] == "S"
    except OSError:
        return False


def test_every_thread_is_listed_with_its_syscall_and_stack(sleeper):
    dump = thread_dump(sleeper.pid)
    listed = [ln for ln in dump.splitlines() if ": S (sleeping), syscall " in ln]
    assert len(listed) >= 2, dump  # the main thread and the sleeper, both asleep in a syscall
    if not shutil.which("gdb"):
        assert "gdb not installed" in dump
    elif "gdb could not attach" not in dump:  # attaching is refused where Yama allows only a parent
        assert dump.count("Thread ") >= 2 and "#0 " in dump, dump


def test_a_failed_test_with_a_live_bridge_reports_the_dump_and_a_passed_one_does_not(pytester):
    pytester.makeconftest(
        f"import importlib.util, subprocess, sys, pytest\n"
        f"spec = importlib.util.spec_from_file_location('bench_conftest', {str(CONFTEST)!r})\n"
        f"bench = importlib.util.module_from_spec(spec); spec.loader.exec_module(bench)\n"
        f"pytest_runtest_makereport = bench.pytest_runtest_makereport\n"
        f"class Bridge:\n"
        f"    proc = None\n"
        f"@pytest.fixture\n"
        f"def bridge():\n"
        f"    b = Bridge(); b.proc = subprocess.Popen({SLEEPER!r}, stdout=subprocess.PIPE, text=True)\n"
        f"    b.proc.stdout.readline()\n"
        f"    yield b\n"
        f"    b.proc.kill(); b.proc.wait()\n")
    pytester.makepyfile("def test_fails(bridge):\n    assert False\n\ndef test_passes(bridge):\n    pass\n")
    result = pytester.runpytest("-p", "no:cacheprovider", "-rA")
    result.assert_outcomes(failed=1, passed=1)
    out = result.stdout.str()
    assert out.count("the bridge's threads when the test failed") == 1, out
    assert "syscall" in out.split("the bridge's threads when the test failed", 1)[1], out
