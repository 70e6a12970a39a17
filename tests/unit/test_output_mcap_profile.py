"""recording.mcap says profile ros2, whose channel user data must carry offered_qos_profiles
(MCAP spec, profiles/ros2.md: "offered_qos_profiles (required, string)"); every channel lacked it."""
from __future__ import annotations

import pytest
from mcap.reader import make_reader
from synthetic import synthetic_run

from canbench import recording

pytestmark = pytest.mark.unit


def test_every_channel_has_the_ros2_profiles_required_metadata(tmp_path):
    recording.write_mcap(synthetic_run(tmp_path), tmp_path / "recording.mcap")
    with open(tmp_path / "recording.mcap", "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        channels = reader.get_summary().channels.values()
    assert channels and all("offered_qos_profiles" in c.metadata for c in channels)
