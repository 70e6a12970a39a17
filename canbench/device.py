"""A device of your own in the bridge's place (`make test DEVICE=host:PORT`, docs/bench.md "A
device of your own"): the bench leaves its `bridge` service out, publishes the router on
127.0.0.1:PORT only (never on every interface), binds the hub's socket directory to a host
directory so a host process joins the bus through libucan-preload.so, and hands the device an
identity of the run (canbench.identities) and the scenario's bridge settings as environment
variables (device.env). The run waits for the device's liveliness token as for the bridge's (or,
for a device that announces nothing, DEVICE_ANNOUNCES=0, for its subscription to the tx keys).

Fault steps on the bridge act on the device: a partition cuts the device's own listener on the
router (its published port leads there), a stop or a kill is bench-run's, which started the device
(DEVICE_CMD) and starts it again, or calls the user's DEVICE_HOOK for a device it does not start
(canbench.device_control). What a device cannot stand in for yet is refused before anything starts:
a stop or a kill of a device started by hand with no hook, the bridge as the
consumer's endpoint or listening where the scenario says (that would be the host's interfaces),
kernel vcan (a host process cannot reach the bus container's namespace)."""
from __future__ import annotations

import re
import shlex
from dataclasses import dataclass

from . import device_control, scenario

IDENTITY = "device"  # its directory among the run's identities; its certificate's CN is "bridge" (the ACL's)
SPEC = re.compile(r"host:(\d{1,5})")
LOWEST_PORT = 1024  # an unprivileged port: the bench never needs root on the host for it


@dataclass(frozen=True)
class Device:
    """A process on this machine, reaching the router on 127.0.0.1:port."""
    port: int

    def endpoint(self, scheme: str = "tls") -> str:
        return f"{scheme}/127.0.0.1:{self.port}"


def parse(spec: str) -> Device:
    """DEVICE's value: host:PORT (the only kind today; a host CAN interface is the next)."""
    m = SPEC.fullmatch(spec)
    if not m:
        raise ValueError(f"DEVICE={spec!r}: expected host:PORT, a process on this machine reaching the router "
                         f"on 127.0.0.1:PORT (e.g. DEVICE=host:7448)")
    port = int(m.group(1))
    if not LOWEST_PORT <= port <= 65535:
        raise ValueError(f"DEVICE={spec!r}: port {port} is not in {LOWEST_PORT}-65535")
    return Device(port)


def refusals(sc: scenario.Scenario, can_mode: str, restartable: bool = False) -> list[str]:
    """Why this scenario cannot run against a device of your own (empty: it can), each at its file.
    restartable: bench-run can stop the device and start it again (it started it, DEVICE_CMD, or the
    user's DEVICE_HOOK does it)."""
    where = str(sc.path)
    out = []
    restarts = sorted({f.action for f in sc.faults if f.action in device_control.ACTIONS})
    if restarts and not restartable:
        out.append(f"{where}: fault steps {', '.join(restarts)} stop the device and start it again, which the "
                   f"bench does only for a device it started (give DEVICE_CMD) or through your hook (DEVICE_HOOK)")
    if sc.consumer == "bridge":
        out.append(f"{where}: topology consumer: bridge reaches the bench's bridge in the bus's namespace; "
                   f"a device of your own is reached through the router")
    if "listen" in sc.bridge:
        out.append(f"{where}: bridge.listen was written for the bench's bridge in the bus's namespace; on the "
                   f"host the device would listen on the host's interfaces")
    if can_mode == "kernel":
        out.append(f"{where}: BENCH_CAN_MODE=kernel: a host process cannot reach the bus container's vcan; "
                   f"a device of your own joins the userspace bus")
    return out


def override(device: Device, canbus_dir: str, router_port: int) -> dict:
    """What compose.yaml changes for the device: the router's port router_port (the bridge's
    listener of a partition scenario, else the router's own) published on loopback only, and the
    hub's socket directory a host directory (bench-run makes it, the bench's user's, 0770)."""
    return {"services": {"router": {"ports": [f"127.0.0.1:{device.port}:{router_port}"]}},
            "volumes": {"canbus": {"driver_opts": {"type": "none", "o": "bind", "device": canbus_dir}}}}


def env_file(settings: dict[str, str]) -> str:
    """The scenario's bridge settings as lines a shell reads with `set -a; . device.env`."""
    return "".join(f"{key}={shlex.quote(value)}\n" for key, value in settings.items())
