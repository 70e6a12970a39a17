"""Traffic planned past duration_s (the upper bound of the traffic phase) is a problem at
duration_s's line, naming whose frame goes out last and when: a trace slowed and looped, a periodic
ECU's run, a command's schedule. Before, validate said ok and the run failed as a bench error once
the whole stack had started and waited duration_s + 30 s."""
from __future__ import annotations

from pathlib import Path

import pytest

from canbench import validate

pytestmark = pytest.mark.unit

# 11 frames over 10 s
TRACE = "".join(f"({1700000000 + k}.000000) vcan0 123#{k:02X}\n" for k in range(11))


def problems(tmp_path: Path, body: str, duration_s: float) -> list[str]:
    (tmp_path / "t.log").write_text(TRACE)
    path = tmp_path / "s.yaml"
    path.write_text(f"name: t\nduration_s: {duration_s}\nbuses: [{{name: vcan0}}]\n{body}"
                    "expect:\n  integrity: true\n")
    return [str(p).removeprefix(f"{path}:") for p in validate.problems(path)]


REPLAY = "ecus:\n  - {name: e, bus: vcan0, trace: t.log, speed: 0.5, loops: 3, start_offset_s: 2}\n"
PERIODIC = "ecus:\n  - {name: g, bus: vcan0, role: periodic, run_s: 30, messages: [{id: '220', cycle_ms: 100}]}\n"
COMMANDS = ("ecus:\n  - {name: e, bus: vcan0, trace: t.log}\n"
            "commands:\n  - {bus: vcan0, messages: [{id: '300', cycle_ms: 500}], run_s: 20, start_offset_s: 5}\n")


@pytest.mark.parametrize("body,end,whose", [
    # 2 s in, then (10 s + the first gap of 1 s) x 2 loops + 10 s at half speed: 66 s
    (REPLAY, "66.000", "ECU e's last frame"),
    (PERIODIC, "29.906", "ECU g's last frame"),  # each id has its own phase within its cycle
    (COMMANDS, "24.509", "the last command (bus vcan0)"),
])
def test_traffic_past_duration_is_a_problem_at_its_line(tmp_path, body, end, whose):
    assert problems(tmp_path, body, 12) == [
        f"2: duration_s: 12 s ends before the traffic does: {whose} goes out at {end} s (speed, loops and start "
        "offsets applied); give duration_s at least that"]
    assert problems(tmp_path, body, float(end) + 0.01) == []
