"""Shared fixtures: one CAN bus per test (kernel vcan where the kernel has it,
else the userspace hub), a zenohd router on a free loopback port, and the
bridge, all from the rig the benchmarks use too (canbench/rig.py). Tools run as
subprocesses so the preload library applies to them exactly as it would to a
user's program."""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from canbench import rig
from canbench.capture import kernel_can_receivers
from canbench.runkeys import open_session, wait_until

REPO = Path(__file__).resolve().parents[1]
BUILD = Path(os.environ.get("UCAN_BUILD", REPO / "build" / "ucan"))
HELPER = Path(__file__).parent / "bus" / "pycan_helper.py"
READY_TIMEOUT_S = 10.0


def kernel_has_vcan() -> bool:
    """True if vcan interfaces exist or can be created here (needs CAP_NET_ADMIN)."""
    probe = "ucanprobe0"
    rc = subprocess.run(["ip", "link", "add", "dev", probe, "type", "vcan"], capture_output=True)
    if rc.returncode != 0:
        return False
    subprocess.run(["ip", "link", "del", probe], capture_output=True)
    return True


def wait_for(condition, what: str, timeout: float = READY_TIMEOUT_S):
    """Poll an explicit readiness condition (never a fixed sleep) until it holds."""
    return wait_until(condition, timeout, what, step_s=0.005)


class Bus:
    """A CAN bus with interfaces vcan0, vcan1 (and vcan2: classic-only, MTU 16)."""

    def __init__(self, mode: str, workdir: Path):
        self.mode = mode
        self.workdir = workdir
        self.env = dict(os.environ)
        self.env.pop("LD_PRELOAD", None)
        self._hub = rig.Hub(BUILD, workdir)
        self.hub_log = self._hub.log
        self.hub_args: list[str] = []

    # -- userspace hub ----------------------------------------------------
    @property
    def hub(self) -> subprocess.Popen | None:
        return self._hub.proc

    def start_hub(self, *ifaces: str) -> None:
        self.hub_args = list(ifaces) or ["vcan0", "vcan1", "vcan2:mtu=16"]
        self.env = dict(self._hub.env)
        self._hub.start(self.hub_args, extra_env={"UCAN_HUB_TEST_FAULT": os.environ.get("UCAN_HUB_TEST_FAULT", "")})

    def stop_hub(self, sig: int = signal.SIGTERM) -> None:
        self._hub.stop(sig)

    def stats(self) -> dict:
        return self._hub.stats()

    # -- either kind ------------------------------------------------------
    def receivers(self) -> int:
        """Number of bound CAN_RAW sockets on the bus (readiness of readers)."""
        if self.mode == "userspace":
            return sum(1 for c in self.stats()["clients"] if c["bound"])
        return kernel_can_receivers()

    def wait_receivers(self, count: int) -> None:
        wait_for(lambda: self.receivers() >= count, f"{count} CAN receiver(s) bound")

    def popen(self, args: list[str], **kw) -> subprocess.Popen:
        kw.setdefault("stdout", subprocess.PIPE)
        kw.setdefault("stderr", subprocess.PIPE)
        kw.setdefault("text", True)
        return subprocess.Popen(args, env=kw.pop("env", self.env), **kw)

    def run(self, args: list[str], check: bool = True, timeout: float = 60, **kw) -> subprocess.CompletedProcess:
        rc = subprocess.run(args, env=kw.pop("env", self.env), capture_output=True, text=True,
                            timeout=timeout, **kw)
        if check and rc.returncode != 0:
            raise AssertionError(f"{args} exited {rc.returncode}: {rc.stderr.strip()}")
        return rc

    def python(self, *args: str, **kw) -> subprocess.Popen:
        """Run pycan_helper.py (python-can) under this bus's environment."""
        return self.popen([sys.executable, str(HELPER), *args], **kw)

    def tool(self, name: str) -> str:
        return str(BUILD / name)


def ensure_kernel_vcan(name: str, mtu: int) -> None:
    """Create / set up a kernel vcan only where sysfs says it differs: under the real-kernel
    lane's emulation every `ip` costs about half a second, and tests leave the links as they are."""
    sysfs = Path("/sys/class/net") / name
    if not sysfs.exists():
        subprocess.run(["ip", "link", "add", "dev", name, "type", "vcan"], check=True)
    if int((sysfs / "mtu").read_text()) != mtu:  # vcan refuses a new MTU while up
        subprocess.run(["ip", "link", "set", name, "down"], check=True)
        subprocess.run(["ip", "link", "set", name, "mtu", str(mtu)], check=True)
    if not int((sysfs / "flags").read_text(), 16) & 0x1:  # IFF_UP
        subprocess.run(["ip", "link", "set", "up", name], check=True)


def bus_modes() -> list[str]:
    """Kernel vcan where it exists (the userspace hub's own features still get tested on the
    hub); the kernel lane is always listed, so a run says why it did not happen here."""
    forced = os.environ.get("BENCH_CAN", "auto")
    if forced in ("kernel", "userspace"):
        return [forced]
    return ["kernel", "userspace"]


KERNEL_VCAN = kernel_has_vcan()


@pytest.fixture(params=bus_modes())
def bus(request, tmp_path_factory):
    if request.param == "kernel" and not KERNEL_VCAN:
        pytest.skip("kernel vcan not available here (no CONFIG_CAN_VCAN module or no CAP_NET_ADMIN): "
                    "the same test runs on the userspace hub")
    workdir = Path(tempfile.mkdtemp(prefix="ucan-", dir="/tmp"))  # short: unix socket paths are limited
    b = Bus(request.param, workdir)
    if b.mode == "userspace":
        b.start_hub()
    else:
        for name in ("vcan0", "vcan1", "vcan2"):
            ensure_kernel_vcan(name, 16 if name == "vcan2" else 72)
    yield b
    b.stop_hub()
    if b.hub_log.exists():  # captured by pytest: shown only when the test failed
        print(f"--- {b.hub_log} ---\n{b.hub_log.read_text()}")
    shutil.rmtree(workdir, ignore_errors=True)


def pytest_collection_modifyitems(config, items):
    for item in items:
        if "bus" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.bus)


def require_userspace(bus: Bus, why: str) -> None:
    if bus.mode != "userspace":
        pytest.skip(f"userspace hub only: {why}")


# -- Zenoh router and bridge ------------------------------------------------------

BRIDGE = Path(os.environ.get("ZN_BRIDGE", REPO / "build" / "firmware" / "zenoh-node"))


class Router(rig.Router):
    """zenohd on a loopback port of the test's directory (skips where there is no zenohd)."""

    def __init__(self, workdir: Path):
        binary = rig.find_zenohd()
        if not binary:
            pytest.skip(f"zenohd {rig.ZENOHD_VERSION} not found (make zenohd, or set ZENOHD)")
        port = rig.free_port()
        super().__init__(binary, workdir / f"zenohd-{port}.log", port)


def zenoh_session(endpoint: str):
    """A client session that fails at once when nothing listens (no retry: tests wait on readiness)."""
    return open_session(endpoint, wait=False)


class Bridge:
    """The zenoh-node executable on a bus, talking to a router."""

    def __init__(self, bus: Bus, router: Router):
        if not BRIDGE.exists():
            pytest.skip(f"bridge not built: {BRIDGE} (make firmware)")
        self.bus, self.router = bus, router
        self.binary = BRIDGE
        self.log = bus.workdir / "bridge.log"
        self.proc: subprocess.Popen | None = None

    def start(self, *args: str, env: dict[str, str] | None = None) -> subprocess.Popen:
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen([str(self.binary), "--router", self.router.endpoint, *args],
                                         stdout=log, stderr=log, env={**self.bus.env, **(env or {})})
        return self.proc

    def wait_ready(self, session, prefix: str = "vehicle/can") -> list[str]:
        """Readiness is the bridge's liveliness token, declared once it forwards both ways."""
        def tokens():
            assert self.proc is None or self.proc.poll() is None, self.log.read_text()
            return rig.bridge_tokens(session, prefix)
        return wait_for(tokens, "the bridge's liveliness token", timeout=30)

    def try_stats(self, session, prefix: str = "vehicle/can", name: str = "zenoh-node") -> dict | None:
        """The bridge's stats queryable, or None while it is unreachable (e.g. reconnecting)."""
        return rig.bridge_stats(session, prefix, name)

    def stats(self, session, prefix: str = "vehicle/can", name: str = "zenoh-node") -> dict:
        stats = self.try_stats(session, prefix, name)
        assert stats is not None, "no reply from the bridge's stats queryable"
        return stats

    def stop(self, sig: int = signal.SIGTERM) -> tuple[int, str]:
        assert self.proc is not None
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        rc = self.proc.wait(timeout=20)
        return rc, self.log.read_text()


# a test gives its router Zenoh's low-latency transport with
# @pytest.mark.parametrize("router", [LOW_LATENCY_ROUTER], indirect=True)
LOW_LATENCY_ROUTER = rig.LOW_LATENCY_ROUTER


@pytest.fixture
def router(bus, request):
    """zenohd for the test; an indirect parameter gives it extra arguments."""
    r = Router(bus.workdir)
    r.start(*getattr(request, "param", ()))
    yield r
    r.stop()
    if r.log.exists():
        print(f"--- {r.log} ---\n{r.log.read_text()[-4000:]}")


@pytest.fixture
def session(router):
    """A Zenoh client session on the test's router."""
    s = zenoh_session(router.endpoint)
    yield s
    s.close()


THREAD_DUMP_TIMEOUT_S = 60.0
THREAD_DUMP_MAX_CHARS = 60_000


def read_field(task: Path, name: str, pick=lambda text: text.strip()) -> str:
    """One /proc file of a thread, '?' where it cannot be read (ended meanwhile, or not ours to trace)."""
    try:
        return pick((task / name).read_text()) or "-"
    except (OSError, StopIteration, IndexError):
        return "?"


def tcp_sockets(pid: int) -> list[tuple[int, int, int, int]]:
    """The process's TCP connections as (local port, remote port, bytes unsent, bytes unread), from
    the kernel's tables: which side of a link holds what when a test finds the link stuck."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = fd.readlink().as_posix()
        except OSError:  # closed meanwhile
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            f = line.split()
            if f[9] in inodes:
                unsent, unread = (int(x, 16) for x in f[4].split(":"))
                found.append((int(f[1].rsplit(":", 1)[1], 16), int(f[2].rsplit(":", 1)[1], 16), unsent, unread))
    return found


def thread_dump(pid: int) -> str:
    """Every thread of a live process: name, state and the syscall it sleeps in (/proc), then each
    stack (gdb, where installed and allowed to attach). What a failing bridge test records before
    teardown stops the bridge: a hang that happens once in a hundred CI runs is then read, not guessed."""
    sockets = tcp_sockets(pid)
    lines = [f"TCP port {local} -> {remote}: {unsent} bytes unsent, {unread} unread"
             for local, remote, unsent, unread in sockets]
    ss = shutil.which("ss")
    if ss and sockets:  # the kernel's view of each: windows, timers (a zero-window probe's backoff), retransmits
        ports = " or ".join(f"sport = :{local}" for local, _, _, _ in sockets)
        try:
            lines.append(subprocess.run([ss, "-tnoi", f"( {ports} )"], capture_output=True, text=True,
                                        timeout=10).stdout.rstrip())
        except subprocess.TimeoutExpired:
            lines.append("(ss took over 10 s)")
    for task in sorted(Path(f"/proc/{pid}/task").glob("*"), key=lambda t: int(t.name)):
        state = read_field(task, "status", lambda t: next(ln.split(None, 1)[1] for ln in t.splitlines()
                                                          if ln.startswith("State:")))
        syscall = read_field(task, "syscall", lambda t: t.split()[0])
        lines.append(f"{task.name} {read_field(task, 'comm')}: {state}, syscall {syscall}, "
                     f"wchan {read_field(task, 'wchan')}")
    gdb = shutil.which("gdb")
    if not gdb:
        lines.append("(gdb not installed: no stacks)")
        return "\n".join(lines)
    try:
        run = subprocess.run([gdb, "-p", str(pid), "-batch", "-nx", "-ex", "set pagination off",
                              "-ex", "set debuginfod enabled off", "-ex", "thread apply all bt"],
                             capture_output=True, text=True, errors="replace", timeout=THREAD_DUMP_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        lines.append(f"(gdb took over {THREAD_DUMP_TIMEOUT_S:.0f} s: no stacks)")
        return "\n".join(lines)
    if "Thread " in run.stdout:
        lines.append(run.stdout[-THREAD_DUMP_MAX_CHARS:])
    else:  # e.g. Yama's ptrace_scope 1: gdb is the process's sibling, not its parent
        why = [ln for ln in run.stderr.splitlines() if ln.strip()][-1:] or ["no output"]
        lines.append(f"(gdb could not attach: {why[0]})")
    return "\n".join(lines)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """A test that failed while its bridge still runs gets the bridge's and its router's thread dumps
    (and their TCP queues) in its report: a stuck link is then seen from both ends."""
    outcome = yield
    report = outcome.get_result()
    if call.when != "call" or not report.failed:
        return
    for name in ("bridge", "router"):
        proc = getattr(getattr(item, "funcargs", {}).get(name), "proc", None)
        if proc is None or proc.poll() is not None:
            continue
        try:
            dump = thread_dump(proc.pid)
        except Exception as e:  # noqa: BLE001 - a diagnostic must never turn a failure into an internal error
            dump = f"(no thread dump: {e!r})"
        report.sections.append((f"the {name}'s threads when the test failed", dump))


@pytest.fixture
def bridge(bus, router):
    b = Bridge(bus, router)
    yield b
    if b.proc and b.proc.poll() is None:
        b.stop(signal.SIGKILL)
    if b.log.exists():
        print(f"--- {b.log} ---\n{b.log.read_text()[-4000:]}")
