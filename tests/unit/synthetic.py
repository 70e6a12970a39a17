"""What several unit tests share (imported from this folder): a synthetic run of smoke.yaml,
its bus trace as the CAN capture and the Zenoh capture without one frame, analysed as a bench
run is; the capture files of a run with commands (write_command_run); a scenario's signal gates
judged on given bus frames (signal_problems)."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from canbench import analysis, checks, oracle, plans, scenario, wire

REPO = Path(__file__).resolve().parents[2]


def synthetic_run(run_dir: Path, lose: int | None = 50) -> analysis.RunResult:
    sc = scenario.load(REPO / "scenarios" / "smoke.yaml")
    (run_dir / "can.log").write_text((REPO / "scenarios" / "traces" / "powertrain-2s.log").read_text())
    with open(run_dir / "zenoh.tsv", "w") as f:  # zn-capture's format
        for i, o in enumerate(oracle.read_candump(run_dir / "can.log", "vcan0")):
            if i != lose:
                f.write(f"{o.t_ns + 400_000}\tvehicle/can/rx\t{wire.encode(o.frame).hex()}\t"
                        f"{wire.encode_attachment(i, [o.t_ns]).hex()}\n")
    return analysis.analyse(sc, "synthetic", run_dir, "vehicle/can", {}, None, 2.0)


def write_command_run(run_dir: Path, t0_ns: int, ecu_frames: int,
                      commands: list[tuple[int, int, wire.Frame, int | None]]) -> None:
    """The captures of a run with commands: the ECU `engine` sends 0C0 every 10 ms from t0 (its
    send log, the bus, and Zenoh 0.5 ms later); commands.tsv has each command (source line, put
    time ns, frame, bus time ns or None: never written), can.log both in time order."""
    ms = 1_000_000
    bus_lines, zenoh_lines = [], []
    with open(run_dir / "commands.tsv", "w") as cmd_log, open(run_dir / "ecu-engine.sent.tsv", "w") as ecu_log:
        cmd_log.write(plans.SENT_LOG_HEADER)
        ecu_log.write(plans.SENT_LOG_HEADER)
        for i in range(ecu_frames):
            f, t = wire.Frame(0x0C0, 1, bytes([i % 256])), t0_ns + i * 10 * ms
            ecu_log.write(plans.sent_line(0, t, f, "vcan0"))
            bus_lines.append((t, f))
            zenoh_lines.append(f"{t + ms // 2}\tvehicle/can/rx\t{wire.encode(f).hex()}\t"
                               f"{wire.encode_attachment(i, [t]).hex()}\n")
        for line, put, f, on_bus in commands:
            cmd_log.write(plans.sent_line(line, put, f, "vcan0"))
            if on_bus is not None:
                bus_lines.append((on_bus, f))
    with open(run_dir / "can.log", "w") as can_log:
        for t, f in sorted(bus_lines, key=lambda x: x[0]):
            can_log.write(f"({t // 10**9}.{t % 10**9 // 1000:06d}) {f.candump('vcan0')}\n")
    (run_dir / "zenoh.tsv").write_text("".join(zenoh_lines))


SIGNAL_T0 = 1_700_000_000_000_000_000


def signal_problems(path: Path, frames: list[wire.Frame], step_ns: int = 10_000_000) -> list[str]:
    """signals_can's problems for a scenario's gates (its DBCs as it names them) on these frames
    of vcan0, step_ns apart from SIGNAL_T0 (can.log:N is the N-th), each forwarded to Zenoh."""
    sc = scenario.load(path)
    bus = [oracle.Observed(f, SIGNAL_T0 + i * step_ns, i, line=i + 1) for i, f in enumerate(frames)]
    zen = [oracle.Observed(f, SIGNAL_T0 + i * step_ns + 400_000, i, key="vehicle/can/rx", seq=i)
           for i, f in enumerate(frames)]
    run_of = SimpleNamespace(signal_gates=sc.signal_gates, bus_dbcs=sc.bus_dbcs, expect={})
    b = SimpleNamespace(bus="vcan0", bus_frames=bus, can_frames=bus, zenoh_frames=zen,
                        comparison=SimpleNamespace(matched=list(zip(bus, zen, strict=True)), corrupted=[]))
    return checks.signals_can(SimpleNamespace(scenario=run_of, buses=[b], metrics={}))
