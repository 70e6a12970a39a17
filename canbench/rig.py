"""The local rig of the tests (tests/conftest.py) and the benchmarks (bench/): the userspace hub,
zenohd, the bridge and the bench's captures as host processes, each started here once, with its
readiness awaited (a signal, never a sleep) and stopped in reverse order. The compose bench starts
the same programs as containers (compose.yaml); this is its host counterpart."""
from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
from pathlib import Path

from .errors import RunError
from .runkeys import wait_token, wait_until

ZENOHD_VERSION = "1.10.2"
READY_TIMEOUT_S = 10.0
STOP_TIMEOUT_S = 10.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def port_open(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def find_zenohd() -> str | None:
    """$ZENOHD (make exports the one it built), the newest zenohd make zenohd built (named by the hash
    of its sources: the patched zenoh crates), a zenohd on PATH, or the images' copy."""
    built = sorted(Path.home().glob(f".cache/canbench/zenohd-{ZENOHD_VERSION}-*/bin/zenohd"),
                   key=lambda p: p.stat().st_mtime, reverse=True)
    candidates = [os.environ.get("ZENOHD"), *map(str, built), shutil.which("zenohd"),
                  f"/opt/zenohd-{ZENOHD_VERSION}/bin/zenohd"]
    return next((c for c in candidates if c and os.access(c, os.X_OK)), None)


def stop(proc: subprocess.Popen, close_stdin: bool = False, sig: int = signal.SIGTERM,
         timeout: float = STOP_TIMEOUT_S) -> int:
    """sig (or the end of stdin, zn-capture's stop), then SIGKILL after timeout; the exit code."""
    if proc.poll() is None:
        if close_stdin and proc.stdin:
            proc.stdin.close()
        else:
            proc.send_signal(sig)
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()


def tail(path: Path, chars: int = 2000) -> str:
    return path.read_text(errors="replace")[-chars:] if path.exists() else ""


class Procs:
    """The processes of one rig: spawned here, stopped in reverse order by close()."""

    def __init__(self) -> None:
        self.procs: list[subprocess.Popen] = []

    def spawn(self, cmd, **kw) -> subprocess.Popen:
        p = subprocess.Popen([str(c) for c in cmd], **kw)
        self.procs.append(p)
        return p

    def add(self, p: subprocess.Popen) -> subprocess.Popen:
        self.procs.append(p)
        return p

    def close(self) -> None:
        for p in reversed(self.procs):
            if p.poll() is None:
                stop(p, close_stdin=p.stdin is not None)

    def __enter__(self) -> Procs:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Hub:
    """ucan-hub on a private directory; env is what a program needs to use its buses."""

    def __init__(self, build: Path, workdir: Path):
        self.build, self.workdir = Path(build), Path(workdir)
        self.env = {k: v for k, v in os.environ.items() if k != "LD_PRELOAD"}
        self.env.update(UCAN_DIR=str(self.workdir), LD_PRELOAD=str(self.build / "libucan-preload.so"))
        self.log = self.workdir / "hub.log"
        self.proc: subprocess.Popen | None = None

    def start(self, ifaces: list[str], *hub_args: str, extra_env: dict | None = None) -> subprocess.Popen:
        """Returns once the hub says ready on its -r pipe."""
        read_fd, write_fd = os.pipe()
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen(
                [str(self.build / "ucan-hub"), "-d", str(self.workdir), "-r", str(write_fd), *hub_args, *ifaces],
                stdout=log, stderr=log, pass_fds=(write_fd,), env={**self.env, "LD_PRELOAD": "", **(extra_env or {})})
        os.close(write_fd)
        with os.fdopen(read_fd) as ready:
            if ready.readline().strip() != "ready":
                raise RunError(f"ucan-hub did not start: {tail(self.log)}")
        return self.proc

    def stats(self) -> dict:
        out = subprocess.run([str(self.build / "ucanctl"), "-d", str(self.workdir), "stats", "-j"],
                             capture_output=True, text=True, check=True)
        return json.loads(out.stdout)

    def bound_sockets(self) -> int:
        """CAN sockets bound on the hub: the readiness of a reader without a signal of its own."""
        try:
            return sum(1 for c in self.stats()["clients"] if c["bound"])
        except subprocess.CalledProcessError:
            return 0

    def wait_bound(self, count: int, timeout: float = READY_TIMEOUT_S) -> None:
        wait_until(lambda: self.bound_sockets() >= count, timeout, f"{count} CAN socket(s) bound", step_s=0.005)

    def reset(self) -> None:
        subprocess.run([str(self.build / "ucanctl"), "-d", str(self.workdir), "reset"], check=True)

    def stop(self, sig: int = signal.SIGTERM) -> None:
        if self.proc:
            stop(self.proc, sig=sig)


# zenohd's settings for Zenoh's low-latency transport (docs/bridge.md): a bridge with --low-latency 1
# uses it only with a router that enables it too
LOW_LATENCY_ROUTER = ("--cfg", "transport/unicast/lowlatency:true", "--cfg", "transport/unicast/qos/enabled:false")


def transport_args(low_latency: bool) -> tuple[tuple[str, ...], list[str]]:
    """(zenohd's arguments, zenoh-node's) for the Zenoh transport a run uses; the universal one adds
    none, so a bridge built before --low-latency existed still runs."""
    return (LOW_LATENCY_ROUTER, ["--low-latency", "1"]) if low_latency else ((), [])


class Router:
    """zenohd on a free loopback port; multicast scouting off (network safety)."""

    def __init__(self, binary: str, log: Path | None = None, port: int | None = None):
        self.binary, self.log = binary, log
        self.port = port or free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.proc: subprocess.Popen | None = None

    def start(self, *extra: str) -> subprocess.Popen:
        """Returns once the router accepts connections (zn-capture and zn-flood try theirs once)."""
        out = open(self.log, "ab") if self.log else subprocess.DEVNULL
        try:
            self.proc = subprocess.Popen([self.binary, "--no-multicast-scouting", "-l", self.endpoint, *extra],
                                         stdout=out, stderr=out)
        finally:
            if self.log:
                out.close()  # type: ignore[union-attr]
        proc = self.proc
        wait_until(lambda: port_open(self.port) or proc.poll() is not None, READY_TIMEOUT_S,
                   f"zenohd on {self.endpoint}", step_s=0.005)
        if proc.poll() is not None:
            raise RunError(f"zenohd on {self.endpoint} exited {proc.returncode}: {tail(self.log) if self.log else ''}")
        return proc

    def stop(self, sig: int = signal.SIGTERM) -> None:
        if self.proc:
            stop(self.proc, sig=sig)


def bridge_tokens(session, prefix: str = "vehicle/can") -> list[str]:
    """The bridges' liveliness tokens under prefix (declared once a bridge forwards both ways)."""
    return [str(r.ok.key_expr) for r in session.liveliness().get(f"{prefix}/bridges/**") if r.ok]


def bridge_stats(session, prefix: str = "vehicle/can", name: str = "zenoh-node") -> dict | None:
    """A bridge's stats queryable, or None while it is unreachable (e.g. reconnecting)."""
    replies = [r for r in session.get(f"{prefix}/bridges/{name}/stats") if r.ok]
    if len(replies) > 1:
        raise RunError(f"{len(replies)} bridges answer as {name}")
    return json.loads(bytes(replies[0].ok.payload.to_bytes())) if replies else None


def start_bridge(procs: Procs, cmd: list, env: dict, log: Path, session, token: str,
                 timeout: float = 30, cwd: Path | None = None) -> subprocess.Popen:
    """A bridge (zenoh-node, the reference, or either under valgrind), ready once its liveliness
    token on `token` exists. session: an open session, or a function that opens one once the
    bridge runs (a bridge that is itself the endpoint, in router mode: no session can open before it)."""
    with open(log, "w") as out:
        p = procs.spawn(cmd, env=env, stdout=out, stderr=subprocess.STDOUT, cwd=cwd)
    opened = session() if callable(session) else session
    try:
        wait_token(opened, token, timeout)
    except TimeoutError:
        raise RunError(f"{cmd[0]} did not come up:\n{tail(log)}") from None
    finally:
        if opened is not session:
            opened.close()
    return p


def zn_capture(procs: Procs, binary: str, endpoint: str, key: str, out: Path, session, token: str,
               timeout: float = 20) -> subprocess.Popen:
    """zn-capture of key into out (TSV), ready once its liveliness token exists; stop: end of stdin."""
    p = procs.spawn([binary, "--connect", endpoint, "--key", key, "--ready-token", token, "--out", out],
                    stdin=subprocess.PIPE, stderr=subprocess.DEVNULL)
    wait_token(session, token, timeout)
    return p


def candump(procs: Procs, env: dict, iface: str, out: Path, *options: str) -> subprocess.Popen:
    """candump -L of iface into out, ready once a probe frame shows in its log (candump has no
    readiness signal of its own); the probe (7FF#, empty) is the log's first line."""
    with open(out, "w") as log:
        p = procs.spawn(["candump", "-L", *options, iface], env=env, stdout=log, stderr=subprocess.DEVNULL)

    def probed() -> bool:
        subprocess.run(["cansend", iface, "7FF#"], env=env, check=True)
        return out.stat().st_size > 0
    wait_until(probed, READY_TIMEOUT_S, "candump reading", step_s=0.05)
    return p


class Rig:
    """A hub on a private directory and the processes one measurement or test starts on its buses."""

    def __init__(self, build: Path, workdir: Path):
        self.workdir = Path(workdir)
        self.hub = Hub(build, workdir)
        self.env = self.hub.env
        self.procs = Procs()

    def spawn(self, cmd, **kw) -> subprocess.Popen:
        return self.procs.spawn(cmd, **kw)

    def close(self) -> None:
        self.procs.close()
        self.hub.stop()
