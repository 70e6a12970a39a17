"""Every ROS 2 type the viewer logs: the catalogue's messages through CDR and the
registry's loggers into an .rrd, read back with Rerun's reader, archetype and
values checked (tests/ros2_catalogue.py). Malformed CDR of every type (truncated,
wrong encapsulation, a huge length at every aligned offset) ends in CdrError or
ValueError, which the viewer counts and skips; never anything else."""
from __future__ import annotations

import numpy as np
import pytest
from ros2_catalogue import CASES, malformed_variants

from canbench import ros2_msgs

pytestmark = pytest.mark.unit
rr = pytest.importorskip("rerun", reason="the viewer needs rerun-sdk (pip install -e '.[viewer]')")

from canbench.viewer import read_rrd_columns  # noqa: E402
from canbench.viewer_types import LOGGERS, Context  # noqa: E402
from canbench.viewer_types.images import UNKNOWN_GREY, occupancy_grey  # noqa: E402


@pytest.fixture(scope="module")
def columns(tmp_path_factory):
    path = tmp_path_factory.mktemp("rrd") / "types.rrd"
    rec = rr.RecordingStream("canbench-test-types")
    rec.save(str(path))
    ctx = Context()
    with rec:
        for case in CASES:
            payload = case.msg.serialize()  # the bytes a publisher sends
            ctx.static = case.topic == "/tf_static"
            LOGGERS[case.type_name](ctx, "ros2" + case.topic, ros2_msgs.decode(case.type_name, payload))
    rec.flush()
    rec.disconnect()
    return read_rrd_columns(path)


def test_every_logged_type_has_a_case():
    assert {c.type_name for c in CASES} == set(LOGGERS) - {"std_msgs/msg/Float64"}  # Float64: recording.mcap's


@pytest.mark.parametrize("case", CASES, ids=[c.topic for c in CASES])
def test_type_logs_its_values(case, columns):
    case.check(columns)


@pytest.mark.parametrize("case", CASES, ids=[c.topic for c in CASES])
def test_malformed_cdr_is_refused_cleanly(case, tmp_path):
    rec = rr.RecordingStream("canbench-test-malformed")
    rec.save(str(tmp_path / "bad.rrd"))
    refused = []
    with rec:
        for i, payload in enumerate(malformed_variants(case.msg.serialize())):
            try:
                msg = ros2_msgs.decode(case.type_name, payload)
                LOGGERS[case.type_name](Context(), "ros2" + case.topic, msg)
            except (ros2_msgs.CdrError, ValueError):
                refused.append(i)
    rec.disconnect()
    assert refused[:8] == list(range(8))  # every truncation and wrong encapsulation; a huge length may fit


def test_occupancy_grey_levels_keep_unknown_apart():
    grey = occupancy_grey(np.arange(-1, 102, dtype=np.int8))
    assert grey[0] == grey[-1] == UNKNOWN_GREY and UNKNOWN_GREY not in grey[1:-1]
    assert grey[1] == 254 and grey[101] == 0 and all(np.diff(grey[1:-1].astype(int)) <= 0)


@pytest.mark.parametrize("option", ["--urdf", "--dbc"])
def test_missing_files_are_named(option, tmp_path):
    import subprocess
    import sys
    missing = tmp_path / "missing.file"
    rc = subprocess.run([sys.executable, "-m", "canbench.cli", "view", option, str(missing), "--save",
                         str(tmp_path / "x.rrd")], capture_output=True, text=True, timeout=60)
    assert rc.returncode == 2 and f"{missing}: {option}: no such file" in rc.stderr
