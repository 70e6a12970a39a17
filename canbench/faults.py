"""Fault steps of a scenario, injected from the orchestrator through Docker's
API (the docker socket is mounted into the orchestrator only, and only for
scenarios with faults; see docs/faults.md for what that privilege means).

Each step acts on a service of the run's compose project (found by the
compose labels) at `at_s` seconds after the traffic starts:

  router_restart  graceful restart (SIGTERM, then start)
  router_kill     SIGKILL, start again after duration_s
  router_pause    frozen for duration_s (sessions time out after the lease)
  router_replace  SIGKILL and a new instance after duration_s (new Zenoh id)
  bridge_term     SIGTERM to the bridge, start again after duration_s
  bridge_kill     SIGKILL to the bridge, start again after duration_s
                  (a device of your own: bench-run's, canbench.device_control)
  ecu_kill        the ECU `target` vanishes for good
  partition       the bridge's link to the router black-holed for duration_s (iptables
                  DROP in the router's network namespace, on the bridge's own listener,
                  where a device of your own is published too)
  can_flood       cangen floods `bus` as fast as the bus takes it for duration_s
                  (at most max_frames; id `id`, data counting up)

Every step records its window (wall clock ns, like the captures) so the
oracle can tell loss inside a fault window from loss outside it. The bridge's
memory use and open file descriptors are sampled all along."""
from __future__ import annotations

import statistics
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from . import device_control
from .scenario import Fault
from .wire import id_hex

ACTION_SERVICE = {"router_restart": "router", "router_kill": "router", "router_pause": "router",
                  "router_replace": "router", "bridge_term": "bridge", "bridge_kill": "bridge",
                  "partition": "router", "can_flood": "orchestrator"}
RSS_SAMPLE_S = 0.5
FD_SAMPLE_S = 5.0  # docker exec costs ~0.1 s of CPU: fds change slowly, memory is cheap to read
# Partition scenarios connect the bridge to this second listener of the router, so a rule
# on it cuts the bridge's link and nothing else (the capture shares the bridge's netns).
PARTITION_PORT = 7446
STOP_TIMEOUT_S = 5  # graceful stops get this long before Docker kills


def disruptive(windows: list[dict]) -> list[dict]:
    """The windows of faults that can interrupt bridging (router, bridge); an ECU vanishing
    only ends that ECU's traffic, so loss around it is never excused."""
    return [w for w in windows if w["action"] != "ecu_kill"]


def cutting(windows: list[dict]) -> list[dict]:
    """The windows of faults that may cut the bridge's link (router and bridge steps, a partition):
    everything sent in one may be lost at once, an outage the oracle looks for there (a flood only
    delays and drops frames of its bus)."""
    return [w for w in disruptive(windows) if w["action"] != "can_flood"]


def last_bridge_restart_ns(windows: list[dict]) -> int:
    """When the bridge's last incarnation was started (0: it never restarted)."""
    return max((w["end_ns"] for w in windows if w["action"].startswith("bridge_")), default=0)


@dataclass
class Window:
    action: str
    service: str
    start_ns: int
    end_ns: int = 0
    error: str = ""

    def as_dict(self, t0_ns: int) -> dict:
        return {"action": self.action, "service": self.service, "start_s": round((self.start_ns - t0_ns) / 1e9, 3),
                "end_s": round((self.end_ns - t0_ns) / 1e9, 3), "start_ns": self.start_ns, "end_ns": self.end_ns,
                "error": self.error}


@dataclass
class Injector:
    """Runs the scenario's fault steps in a thread; samples the bridge's memory in another."""
    project: str
    faults: list[Fault]
    on_ecu_killed: object = None  # callable(name) so the orchestrator stops waiting for it
    sample_bridge: bool = True  # False: a device of your own is under test, no bridge container to sample
    # a device of your own: the run's directory, where bench-run serves its stops and restarts
    device_dir: Path | None = None
    windows: list[Window] = field(default_factory=list)
    rss_samples: list[tuple[int, float]] = field(default_factory=list)  # (ns, MiB)
    fd_samples: list[tuple[int, int]] = field(default_factory=list)  # (ns, open fds)
    errors: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        import docker  # only fault scenarios need Docker's API
        self.client = docker.from_env()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    def container(self, service: str):
        found = self.client.containers.list(all=True, filters={"label": [
            f"com.docker.compose.project={self.project}", f"com.docker.compose.service={service}"]})
        if not found:
            raise RuntimeError(f"no container of service {service} in project {self.project}")
        return found[0]

    def start(self) -> None:
        self.t0_ns = time.time_ns()
        t0 = time.monotonic()
        self._threads = [threading.Thread(target=self._run, args=(t0,), daemon=True, name="faults")]
        if self.sample_bridge:
            self._threads.append(threading.Thread(target=self._sample_rss, daemon=True, name="rss"))
        for t in self._threads:
            t.start()

    def _run(self, t0: float) -> None:
        for fault in sorted(self.faults, key=lambda f: f.at_s):
            if self._stop.wait(max(0.0, t0 + fault.at_s - time.monotonic())):
                return  # the run ended first
            # a stop or a kill of a device of your own is bench-run's (device_control)
            device_dir = self.device_dir if fault.action in device_control.ACTIONS else None
            service = "device" if device_dir else fault.target and f"ecu-{fault.target}" or ACTION_SERVICE[fault.action]
            window = Window(fault.action, service, time.time_ns())
            self.windows.append(window)
            exact = None
            try:
                if device_dir:
                    exact = device_control.restart(device_dir, fault.action, fault.duration_s)
                else:
                    exact = self._inject(fault, None if fault.action == "can_flood" else self.container(service))
            except Exception as e:  # noqa: BLE001 - reported as the bench's failure, never lost in a thread
                window.error = f"{type(e).__name__}: {e}"
                self.errors.append(f"{fault.action} on {service}: {window.error}")
            window.end_ns = time.time_ns()
            if exact:  # when the fault really began and ended, not when the Docker calls returned
                window.start_ns, window.end_ns = exact

    def _inject(self, fault: Fault, c) -> tuple[int, int] | None:
        hold = fault.duration_s
        if fault.action == "router_restart":
            c.restart(timeout=STOP_TIMEOUT_S)
        elif fault.action in ("router_kill", "router_replace", "bridge_kill"):
            c.kill()
            time.sleep(hold)  # the fault's length, as the scenario specifies
            c.start()
        elif fault.action == "bridge_term":
            c.stop(timeout=STOP_TIMEOUT_S)
            time.sleep(hold)
            c.start()
        elif fault.action == "router_pause":
            c.pause()
            time.sleep(hold)
            c.unpause()
        elif fault.action == "partition":
            cut_ns = self._iptables(c, "-I")
            try:
                time.sleep(hold)
            finally:
                healed_ns = self._iptables(c, "-D")
            return cut_ns, healed_ns
        elif fault.action == "can_flood":
            self._flood(fault)
        elif fault.action == "ecu_kill":
            c.kill()
            if callable(self.on_ecu_killed):
                self.on_ecu_killed(fault.target)
        else:
            raise ValueError(f"unknown fault action {fault.action}")
        return None

    def _iptables(self, router, op: str) -> int:
        """Insert (-I) or delete (-D) the partition's rules in the router's network namespace,
        from a throw-away container of the bus image (it has iptables): the router's image and
        privileges stay as they are. Returns when the rules took effect (wall clock ns, printed
        by the container: its start and removal take a fraction of a second either side)."""
        rules = [f"INPUT -p tcp --dport {PARTITION_PORT} -j DROP", f"OUTPUT -p tcp --sport {PARTITION_PORT} -j DROP"]
        script = " && ".join([*(f"iptables {op} {r}" for r in rules), "date +%s%N"])
        out = self.client.containers.run(self.container("bus").image.id, ["-c", script], entrypoint="sh", user="0",
                                         network_mode=f"container:{router.id}", cap_add=["NET_ADMIN"], remove=True)
        return int(out.decode().split()[-1])

    @staticmethod
    def _flood(fault: Fault) -> None:
        """cangen with no gap (-g 0) ignoring ENOBUFS (-i): all the bus takes, bounded in count and time."""
        proc = subprocess.Popen(["cangen", fault.bus, "-g", "0", "-i", "-I", id_hex(fault.can_id, False), "-L", "8",
                                 "-D", "i", "-n", str(fault.max_frames)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            _, err = proc.communicate(timeout=fault.duration_s)
        except subprocess.TimeoutExpired:
            proc.terminate()
            _, err = proc.communicate(timeout=STOP_TIMEOUT_S)
        if proc.returncode not in (0, -15):
            raise RuntimeError(f"cangen exited {proc.returncode}: {err.decode().strip()}")

    def _sample_rss(self) -> None:
        next_fd_sample = 0.0
        while not self._stop.wait(RSS_SAMPLE_S):
            if time.monotonic() >= next_fd_sample:
                next_fd_sample = time.monotonic() + FD_SAMPLE_S
                self._sample_fds()
            try:
                stats = self.container("bridge").stats(stream=False)
                usage = stats.get("memory_stats", {})
                rss = usage.get("stats", {}).get("rss", usage.get("stats", {}).get("anon", usage.get("usage", 0)))
                if rss:
                    self.rss_samples.append((time.time_ns(), rss / 2**20))
            except Exception:  # noqa: BLE001 - the bridge may be down during its own fault
                continue

    def _sample_fds(self) -> None:
        try:  # the bridge is PID 1 of its container (bench-can execs it) and runs as the exec's user
            code, out = self.container("bridge").exec_run(["sh", "-c", "ls /proc/1/fd | wc -l"])
            if code == 0:
                self.fd_samples.append((time.time_ns(), int(out)))
        except Exception:  # noqa: BLE001 - the bridge may be down during its own fault
            pass

    def wait_faults(self, timeout_s: float) -> None:
        """Until every fault step has run (and restarted what it stopped)."""
        self._threads[0].join(timeout=timeout_s)
        if self._threads[0].is_alive():
            raise TimeoutError(f"fault steps still running after {timeout_s:.0f} s")

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=30)

    def summary(self) -> dict:
        rss = [m for _, m in self.rss_samples]
        fds = [n for _, n in self.fd_samples]
        return {"windows": [w.as_dict(self.t0_ns) for w in self.windows], "errors": self.errors,
                "bridge_rss_mib": {"max": round(max(rss), 2) if rss else None, "samples": len(rss),
                                   "first": round(rss[0], 2) if rss else None,
                                   "last": round(rss[-1], 2) if rss else None,
                                   "slope_mib_per_h": rss_slope_mib_per_h(self.rss_samples)},
                "bridge_fds": {"max": max(fds) if fds else None, "samples": len(fds),
                               "growth": fd_growth(fds)},
                "series": {"rss": [(round((t - self.t0_ns) / 1e9, 2), round(m, 3)) for t, m in self.rss_samples],
                           "fds": [(round((t - self.t0_ns) / 1e9, 2), n) for t, n in self.fd_samples]}}


def rss_slope_mib_per_h(samples: list[tuple[int, float]]) -> float | None:
    """Least-squares slope of memory over time, skipping the first tenth (start-up allocations)."""
    kept = samples[len(samples) // 10:]
    if len(kept) < 10:
        return None
    slope = statistics.linear_regression([t / 3.6e12 for t, _ in kept], [m for _, m in kept]).slope
    return round(slope, 3)


def fd_growth(fds: list[int]) -> int | None:
    """Open descriptors: median of the last quarter minus median of the first (reconnects come and go)."""
    if len(fds) < 8:
        return None
    quarter = len(fds) // 4
    return int(statistics.median(fds[-quarter:]) - statistics.median(fds[:quarter]))
