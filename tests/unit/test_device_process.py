"""bench-run's side of a fault step on a device of your own (scripts/device-process.sh, sourced
as bench-run sources it): a kill and a stop of the device's whole process group and the command
run again, the window answered; a device that ignores TERM killed after DEVICE_STOP_S; a device
that had already exited not started again (its exit stays the run's verdict); the orchestrator's
FIFOs never the device's; bad requests answered with why. The orchestrator's side is
tests/unit/test_device_control.py, the whole run tests/compose/test_device.py."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

LIB = Path(__file__).resolve().parents[2] / "scripts" / "device-process.sh"
# says it is ready (the file "ignoring") once TERM is ignored: a TERM before would end it
IGNORES_TERM = (f"exec {sys.executable} -c 'import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
                "open(\"ignoring\", \"w\").close(); time.sleep(300)'")


def bench_run(tmp_path: Path, command: str, steps: str, **env: str) -> list[str]:
    """The library with bench-run's variables, DEVICE_CMD launched, then `steps` (bash); what they
    print, line by line. Whatever the device left is killed at the end."""
    (tmp_path / "ids" / "device").mkdir(parents=True)
    (tmp_path / "ids" / "device.env").write_text("ZENOH_NODE_CAN=vcan0\n")
    script = f"""set -euo pipefail
. {LIB}
identities={tmp_path}/ids device_endpoint=tls/127.0.0.1:1 canbus_dir={tmp_path} repo={tmp_path}
caller_dir={tmp_path} run_dir={tmp_path} device_pid='' device_group=''
trap 'stop_device' EXIT
gone() {{  # until process $1 is gone (bounded)
	local deadline=$((SECONDS + 10))
	while kill -0 -- "$1" 2>/dev/null && [ $SECONDS -lt $deadline ]; do sleep 0.02; done
}}
launch_device
{steps}
"""
    proc = subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "DEVICE_CMD": command, "DEVICE_STOP_S": "1", **env})
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.splitlines()


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.mark.parametrize("action", ["bridge_kill", "bridge_term"])
def test_a_stop_or_a_kill_restarts_the_devices_command_and_answers_the_window(tmp_path, action):
    # the device notes when it starts: the window's end comes before its new incarnation's first act
    # (the checks count the new incarnation's frames from there on)
    first, answer, second = bench_run(tmp_path, "date +%s%N >>starts; exec sleep 300", f"""
echo $device_pid
device_fault 7 {action} 0.2
echo $device_pid
deadline=$((SECONDS + 10))
until [ "$(wc -l <"$caller_dir/starts")" -ge 2 ] || [ $SECONDS -ge $deadline ]; do sleep 0.02; done""")
    seq, word, stopped, started = answer.split()
    assert (seq, word) == ("7", "ok")
    assert int(started) - int(stopped) >= 0.2e9  # the step's hold
    assert int(started) <= int((tmp_path / "starts").read_text().split()[-1])
    assert first != second and not alive(int(first))
    assert f"device: {action}, started again after 0.2s" in (tmp_path / "device.log").read_text()


def test_a_device_that_ignores_term_is_killed_after_device_stop_s(tmp_path):
    [answer] = bench_run(tmp_path, IGNORES_TERM, """
deadline=$((SECONDS + 10)); until [ -e "$caller_dir/ignoring" ] || [ $SECONDS -ge $deadline ]; do sleep 0.02; done
device_fault 1 bridge_term 0""", DEVICE_STOP_S="2")
    _, word, stopped, started = answer.split()
    # (bash's clock for DEVICE_STOP_S is in whole seconds: 2 is 1-2 s)
    assert word == "ok" and 1e9 <= int(started) - int(stopped) < 5e9


def test_a_device_that_had_exited_is_not_started_again_and_its_exit_stays(tmp_path):
    answer, status = bench_run(tmp_path, "exit 3", """
gone $device_pid
device_fault 2 bridge_term 0
wait $device_pid && echo 0 || echo $?""")
    assert answer == "2 error the device had exited before bridge_term"
    assert status == "3"  # what bench-run's verdict says: the device exited with 3
    assert "started again" not in (tmp_path / "device.log").read_text()


def test_the_orchestrators_fifos_are_not_the_devices(tmp_path):
    [fds] = bench_run(tmp_path, "exec sleep 300", f"""
mkfifo {tmp_path}/device.request {tmp_path}/device.reply
exec {{requests}}<>{tmp_path}/device.request {{replies}}<>{tmp_path}/device.reply
device_fault 1 bridge_kill 0 >/dev/null
ls -l /proc/$device_pid/fd | tr '\\n' ' '""")
    assert "device.re" not in fds and "sleep" not in fds, fds


@pytest.mark.parametrize("request_, says", [("1 bridge_pause 1", "1 error bridge_pause is not a fault step"),
                                            ("2 bridge_kill x", "2 error hold 'x': not a number of seconds"),
                                            ("3 bridge_kill 1.2.3", "3 error hold '1.2.3'")])
def test_a_request_that_is_not_a_step_is_answered_with_why(tmp_path, request_, says):
    [answer, same] = bench_run(tmp_path, "exec sleep 300", f"""
first=$device_pid
device_fault {request_}
[ "$device_pid" = "$first" ] && kill -0 $first && echo same""")
    assert answer.startswith(says) and same == "same"  # the device untouched


# --- a device the bench does not start: the user's DEVICE_HOOK stops and starts it


def hook_run(tmp_path: Path, hook: str, steps: str, **env: str) -> list[str]:
    """The library with bench-run's variables and DEVICE_HOOK, no DEVICE_CMD (nothing launched),
    then `steps`; what they print, line by line. The hook's calls are in the caller's directory."""
    script = f"""set -euo pipefail
. {LIB}
caller_dir={tmp_path} run_dir={tmp_path} device_pid='' device_group='' hook_stopped=''
identities={tmp_path}/ids device_endpoint=tls/127.0.0.1:7448 canbus_dir={tmp_path}/bus repo={tmp_path}
{steps}
"""
    proc = subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "DEVICE_HOOK": hook, **env})
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.splitlines()


# the hook notes each call with its arguments and the time it began (the window's check)
NOTING_HOOK = 'f() { echo "$* $(date +%s%N)" >>calls; }; f'


@pytest.mark.parametrize("action", ["bridge_kill", "bridge_term"])
def test_a_hook_is_called_to_stop_then_after_the_hold_to_start_and_the_window_answered(tmp_path, action):
    [answer, left] = hook_run(tmp_path, NOTING_HOOK, f"""
device_fault 4 {action} 0.2
echo "left=$hook_stopped" """)
    seq, word, stopped, started = answer.split()
    assert (seq, word) == ("4", "ok") and left == "left="
    (stop, stop_action, stop_ns), (start, start_action, start_ns) = \
        (line.split() for line in (tmp_path / "calls").read_text().splitlines())
    assert (stop, stop_action, start, start_action) == ("stop", action, "start", action)
    # the window opens before the stop's call and ends before the start's, the hold between
    assert int(stopped) <= int(stop_ns) and int(started) <= int(start_ns)
    assert int(started) - int(stopped) >= 0.2e9
    assert f"DEVICE_HOOK stop {action}" in (tmp_path / "device.log").read_text()


@pytest.mark.parametrize("hook, says", [
    ('f() { [ "$1" = start ] || exit 5; }; f', "DEVICE_HOOK stop bridge_kill exited with 5"),
    ('f() { [ "$1" = stop ] || exit 6; }; f', "DEVICE_HOOK start bridge_kill exited with 6"),
    ('f() { [ "$1" = start ] || exec sleep 30; }; f',
     "DEVICE_HOOK stop bridge_kill did not finish within DEVICE_HOOK_TIMEOUT_S=1 s"),
    ('f() { [ "$1" = start ] || exit 124; }; f', "DEVICE_HOOK stop bridge_kill exited with 124")])
def test_a_hook_that_fails_or_hangs_is_answered_with_why(tmp_path, hook, says):
    [answer] = hook_run(tmp_path, hook, "device_fault 9 bridge_kill 0", DEVICE_HOOK_TIMEOUT_S="1")
    assert answer.startswith("9 error " + says), answer


def test_a_stop_by_the_hook_without_its_start_is_what_the_runs_end_gives_back(tmp_path):
    # a stop that failed (the device's state unknown) leaves its start to bench-run's cleanup
    [left] = hook_run(tmp_path, 'f() { [ "$1" = start ] || exit 5; }; f', """
device_fault 9 bridge_term 0 >/dev/null
echo "$hook_stopped" """)
    assert left == "bridge_term"


def test_the_orchestrators_fifos_are_not_the_hooks(tmp_path):
    hook_run(tmp_path, 'f() { ls -l /proc/self/fd >>fds; }; f', f"""
mkfifo {tmp_path}/device.request {tmp_path}/device.reply
exec {{requests}}<>{tmp_path}/device.request {{replies}}<>{tmp_path}/device.reply
device_fault 1 bridge_kill 0 >/dev/null""")
    fds = (tmp_path / "fds").read_text()
    assert fds.count("total") == 2 and "device.re" not in fds, fds


def test_a_hook_is_told_the_step_and_the_runs_identity_router_and_bus(tmp_path):
    hook_run(tmp_path, 'f() { env | grep -E "^DEVICE_(HOOK_|ZENOH|ENV|ROUTER|UCAN|PRELOAD)" | sort >>env; }; f',
             "device_fault 1 bridge_term 0 >/dev/null")
    told = (tmp_path / "env").read_text().splitlines()
    assert told[:7] == [
        f"DEVICE_ENV_FILE={tmp_path}/ids/device.env", "DEVICE_HOOK_ACTION=stop", "DEVICE_HOOK_STEP=bridge_term",
        f"DEVICE_PRELOAD={tmp_path}/build/ucan/libucan-preload.so", "DEVICE_ROUTER_ADDRESS=tls/127.0.0.1:7448",
        f"DEVICE_UCAN_DIR={tmp_path}/bus", f"DEVICE_ZENOH_CONFIG={tmp_path}/ids/device/zenoh.json5"]
    assert told[7:] == [line.replace("=stop", "=start") for line in told[:7]]


def test_an_interrupt_during_the_hooks_start_does_not_call_it_again_at_the_runs_end(tmp_path):
    # bench-run's traps: an interrupt lets the start's call finish, then its cleanup gives back a
    # device left stopped; the one already being started is not started twice. The start's call
    # says it began and then waits until the interrupt was sent (two FIFOs): the TERM lands in it
    hook = ('f() { echo "$1 began" >>calls; '
            'if [ "$1" = start ]; then echo >began; exec 3<>go; read -r -t 10 _ <&3; fi; echo "$1" >>calls; }; f')
    hook_run(tmp_path, hook, """
mkfifo "$caller_dir/began" "$caller_dir/go"
(
\ttrap - EXIT
\tcleanup() { [ -z "${hook_stopped:-}" ] || run_hook start "$hook_stopped" || true; }
\ttrap cleanup EXIT
\ttrap 'exit 130' TERM
\tme=$BASHPID
\t(
\t\texec 4<>"$caller_dir/began"
\t\tread -r -t 10 _ <&4  # the start's call began
\t\tkill -TERM $me
\t\techo >"$caller_dir/go"
\t) &
\tdevice_fault 1 bridge_kill 0.1 >/dev/null
) || true""")
    calls = (tmp_path / "calls").read_text().splitlines()
    assert calls == ["stop began", "stop", "start began", "start"], calls
