"""A stop or a kill of a device of your own (fault steps bridge_term, bridge_kill), asked of
bench-run: it started the device on the host (DEVICE_CMD), so only it can signal the device's
process group and start the command again, and it runs the user's DEVICE_HOOK for a device it does
not start (a board's power); the orchestrator, in a container, reaches neither. Two FIFOs in the
run's directory (the host's and the orchestrator's, both mounted), made and held open by bench-run
for a run with DEVICE_CMD or DEVICE_HOOK:

  device.request  the orchestrator writes "SEQ ACTION HOLD_S\\n" (one write: atomic in a pipe)
  device.reply    bench-run answers "SEQ ok STOPPED_NS STARTED_NS\\n" (wall clock: when the signal
                  went, or the hook was called to stop it, and when the command was started
                  again, or the hook called to start it) or "SEQ error WHY\\n"

bench-run serves one request at a time from its watch loop (scripts/bench-run, device_fault); an
answer to an earlier request, given up on, is told apart by its SEQ."""
from __future__ import annotations

import itertools
import os
import select
import time
from pathlib import Path

REQUEST, REPLY = "device.request", "device.reply"
ACTIONS = ("bridge_term", "bridge_kill")  # the steps served so (bench-run refuses any other)
# bench-run's stop waits DEVICE_STOP_S (default 10 s) before it kills; the reply comes after the hold
# (a DEVICE_STOP_S near this long makes a device that ignores TERM a bench error)
REPLY_MARGIN_S = 60.0
_requests = itertools.count(1)


def restart(run_dir: Path, action: str, hold_s: float, margin_s: float = REPLY_MARGIN_S) -> tuple[int, int]:
    """Stop the device (bridge_term: TERM, bridge_kill: KILL), start it again after hold_s; the
    fault's window as bench-run measured it. RuntimeError: nobody serves the request, or its answer."""
    try:
        reply = os.open(run_dir / REPLY, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        raise RuntimeError(f"no {REPLY} in {run_dir}: bench-run stops and starts only a device it started "
                           "(DEVICE_CMD) or one with a hook (DEVICE_HOOK)") from None
    try:
        _drain(reply)  # nothing a request given up on left behind is taken for this one's answer
        try:
            request = os.open(run_dir / REQUEST, os.O_WRONLY | os.O_NONBLOCK)
        except OSError as e:  # ENXIO: no reader, bench-run is not serving
            raise RuntimeError(f"bench-run does not serve {run_dir / REQUEST}: {e}") from None
        seq = str(next(_requests))
        try:
            os.write(request, f"{seq} {action} {hold_s:.3f}\n".encode())  # bench-run reads a plain decimal
        finally:
            os.close(request)
        deadline = time.monotonic() + hold_s + margin_s
        while True:
            answer, _, line = _line(reply, deadline).partition(" ")
            if answer == seq:
                break
    finally:
        os.close(reply)
    word, _, rest = line.partition(" ")
    if word == "ok":
        stopped, started = (int(v) for v in rest.split())
        return stopped, started
    raise RuntimeError(f"bench-run could not {action} the device: {rest or line}")


def _drain(fd: int) -> None:
    while select.select([fd], [], [], 0)[0] and os.read(fd, 4096):
        pass


def _line(fd: int, deadline: float) -> str:
    """One line from a non-blocking FIFO, waiting for it until deadline (monotonic s). Reads a byte
    at a time: what follows the line stays in the pipe for the next call."""
    got = b""
    while not got.endswith(b"\n"):
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            raise RuntimeError(f"no answer from bench-run in time (got {got.decode(errors='replace')!r})")
        chunk = os.read(fd, 1)
        if not chunk:  # every writer gone: bench-run stopped serving
            raise RuntimeError("bench-run closed the device's reply before answering")
        got += chunk
    return got.decode(errors="replace").strip()
