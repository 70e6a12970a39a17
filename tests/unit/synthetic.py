"""What several unit tests share (imported from this folder): a synthetic run of smoke.yaml,
its bus trace as the CAN capture and the Zenoh capture without one frame, analysed as a bench
run is."""
from __future__ import annotations

from pathlib import Path

from canbench import analysis, oracle, scenario, wire

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
