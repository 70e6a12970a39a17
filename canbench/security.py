"""The security scenario's probes (scenarios/security.yaml, docs/access-control.md): containers on
the bench network that try to put commands on the bridge's tx key with the wrong credentials, and
a bridge with a certificate of another CA. Each probe writes what happened to
probe-<name>.json in the run's directory; the orchestrator waits for those files (observe),
looks for the rogue bridge's liveliness token, and writes security.json; the check
`access_control` (canbench.checks) judges both with the bus capture and the bridge's stats.

Probes (scenario key `security.probes`):
  anonymous     no certificate at all (it trusts the router's CA, so the refusal is the
                router's), then plain tcp on the same port: must get no session
  ecu           the ECU's identity: gets a session (the run's coordination keys) but its
                puts on the tx key must reach neither the bridge nor the bus
  rogue-bridge  the bridge's common name, signed by another CA: must get no session
and, with rogue-bridge, a real zenoh-node with that certificate (service bridge-rogue, node
name `rogue`) whose token must never appear."""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import zenoh

from . import runkeys, wire

PROBES = ("anonymous", "ecu", "rogue-bridge")
PROBE_IDS = {"anonymous": 0x666, "ecu": 0x667, "rogue-bridge": 0x668}  # never a command's or an ECU's id
ROGUE_NODE = "rogue"  # the rogue zenoh-node's name: its token would be <prefix>/bridges/rogue/...
CONNECT_TIMEOUT_MS = 5000
PROBES_TIMEOUT_S = 60
CAPTURE_READY_TIMEOUT_S = 120  # as long as an ECU waits for it


def spec(scenario) -> dict | None:
    """The scenario's security section, or None."""
    return scenario.raw.get("security")


def probe_file(run_dir: Path, name: str) -> Path:
    return run_dir / f"probe-{name}.json"


def _session(endpoint: str, config_file: str | None, wait: bool) -> zenoh.Session:
    conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/timeout_ms", "-1" if wait else str(CONNECT_TIMEOUT_MS))
    return zenoh.open(conf)


def probe(name: str, endpoint: str, run_id: str, run_dir: Path, frames: int, prefix: str = "vehicle/can",
          config_file: str | None = None) -> dict:
    """One probe: a session with config_file's credentials (none: no certificate), then, if it got
    one, `frames` puts on the tx key once the run's capture is ready. The anonymous probe also
    tries plain tcp. Writes and returns probe-<name>.json's content."""
    result: dict = {"probe": name, "attempts": [], "session": False, "put": 0, "id": PROBE_IDS[name]}
    endpoints = [endpoint]
    if name == "anonymous" and endpoint.startswith("tls/"):
        endpoints.append("tcp/" + endpoint.removeprefix("tls/"))
    session = None
    for ep in endpoints:
        try:
            # the ECU's identity is valid: wait for the router like any ECU; the others must be refused
            session = _session(ep, config_file if name != "anonymous" or not ep.startswith("tcp/") else None,
                               wait=name == "ecu")
            result["attempts"].append({"endpoint": ep, "session": True})
            break
        except zenoh.ZError as e:
            result["attempts"].append({"endpoint": ep, "session": False, "error": str(e).split(" at ")[0]})
    if session is not None:
        result["session"] = True
        try:
            try:  # a probe without the coordination keys' rights never sees this token: put anyway
                runkeys.wait_token(session, runkeys.capture_ready(run_id), CAPTURE_READY_TIMEOUT_S)
                result["capture_ready_seen"] = True
            except TimeoutError:
                result["capture_ready_seen"] = False
            for i in range(frames):
                session.put(f"{prefix}/tx", wire.encode(wire.Frame(PROBE_IDS[name], 2, bytes([i & 0xFF, 0xAC]))))
                result["put"] += 1
            # a query through the router after the puts (its final reply comes back at once: no
            # queryable there): the router has handled every put before it
            list(session.get(f"bench/runs/{run_id}/probes/{name}/sync", timeout=5))
        finally:
            session.close()
    path = probe_file(run_dir, name)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(result, indent=1) + "\n")
    os.replace(tmp, path)
    return result


def observe(run) -> None:
    """The orchestrator's side (canbench.run, after the traffic): waits for every probe's file,
    looks for the rogue bridge's token, writes security.json. No-op without a security section."""
    sec = spec(run.scenario)
    if not sec:
        return
    names = list(sec.get("probes", PROBES))
    files = {n: probe_file(run.run_dir, n) for n in names}
    try:
        runkeys.wait_until(lambda: all(f.exists() for f in files.values()), PROBES_TIMEOUT_S,
                           f"the probes' results ({', '.join(sorted(files))})", step_s=0.1)
    except TimeoutError:
        pass  # the check names the missing ones
    key = f"{run.prefix}/bridges/{ROGUE_NODE}/**"
    # a subscriber with history, and a query (it returns at its final reply): zenoh 1.10's answer
    # to a liveliness query can miss a token an earlier query on the same key did not find
    seen: set[str] = set()
    sub = run.session.liveliness().declare_subscriber(key, lambda s: seen.add(str(s.key_expr)), history=True)
    try:
        seen |= {str(r.ok.key_expr) for r in run.session.liveliness().get(key, timeout=10) if r.ok}
    finally:
        sub.undeclare()
    rogue_tokens = sorted(seen)
    out = {"probes": {n: json.loads(f.read_text()) if f.exists() else None for n, f in files.items()},
           "rogue_bridge_tokens": rogue_tokens if "rogue-bridge" in names else None}
    (run.run_dir / "security.json").write_text(json.dumps(out, indent=1) + "\n")
    for line in refusals(run.run_dir):  # the run says what the router did with each probe
        print(f"canbench: security: {line}", file=sys.__stderr__, flush=True)


def check(result) -> list[str] | None:
    """access_control: no probe got what it must not, nothing of theirs reached the bridge or the
    bus, and the ECU's probe did put (else it proved nothing)."""
    sec = spec(result.scenario)
    if not sec:
        return None
    path = result.run_dir / "security.json"
    if not path.exists():
        return ["no security.json: the orchestrator did not observe the probes"]
    seen = json.loads(path.read_text())
    problems = []
    for name, r in seen["probes"].items():
        if r is None:
            problems.append(f"probe {name}: no result (probe-{name}.json missing; see containers.log)")
            continue
        opened = [a["endpoint"] for a in r["attempts"] if a["session"]]
        if name == "ecu":
            if not r["session"]:
                problems.append(f"probe ecu: the ECU's identity got no session ({r['attempts']}): the probe "
                                "proved nothing")
            elif r["put"] < sec.get("frames", 1):
                problems.append(f"probe ecu: put only {r['put']} of {sec.get('frames', 1)} frames")
        elif opened:
            refuse = "a client without a certificate" if name == "anonymous" else "a certificate of another CA"
            problems.append(f"probe {name}: the router gave it a session on {opened[0]} (it must refuse {refuse})")
    if seen.get("rogue_bridge_tokens"):
        problems.append(f"the rogue bridge (certificate of another CA) is on the network: "
                        f"{seen['rogue_bridge_tokens']}")
    ids = {PROBE_IDS[n] for n in seen["probes"]}
    for b in result.buses:
        on_bus = [r for r in (b.zenoh_to_can.unexpected if b.zenoh_to_can else []) if r.frame.can_id in ids]
        if on_bus:
            problems.append(f"{b.bus}: {len(on_bus)} of the probes' frames reached the bus "
                            f"(ids {sorted({hex(r.frame.can_id) for r in on_bus})})")
    if result.bridge_stats:
        commands = sum(len(b.commands) for b in result.buses if b.commands)
        received = sum(s.get("tx_samples", 0) for s in result.bridge_stats["buses"])
        if received > commands:
            problems.append(f"the bridge received {received} samples on its tx keys, the orchestrator put {commands}: "
                            f"{received - commands} came from a probe")
    return problems


def refusals(run_dir: Path) -> list[str]:
    """One line per probe for bench-run's summary: what the router did with it."""
    path = run_dir / "security.json"
    if not path.exists():
        return []
    seen = json.loads(path.read_text())
    lines = []
    for name, r in seen["probes"].items():
        if r is None:
            lines.append(f"{name}: no result")
        elif r["session"]:
            lines.append(f"{name}: got a session, put {r['put']} frames on the tx key")
        else:
            why = "; ".join(f"{a['endpoint']}: {a.get('error', '')}" for a in r["attempts"])
            lines.append(f"{name}: refused ({why})")
    tokens = seen.get("rogue_bridge_tokens")
    if tokens is not None:
        lines.append(f"bridge-rogue: {f'ON THE NETWORK {tokens}' if tokens else 'never joined (no token)'}")
    return lines
