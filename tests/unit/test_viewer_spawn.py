"""The viewer `canbench view` spawns listens on loopback only and sends no usage data: its launcher
passes --bind 127.0.0.1 (the rerun binary binds every interface unless told) and runs it with a
configuration directory of the bench's own where Rerun's analytics are disabled."""
from __future__ import annotations

import json
import subprocess

import pytest

from canbench import viewer_spawn

pytestmark = pytest.mark.unit


def test_the_launcher_binds_loopback_with_analytics_disabled(tmp_path):
    rerun = viewer_spawn.rerun_binary()
    script = viewer_spawn.launcher(rerun, tmp_path)
    text = script.read_text()
    assert "--bind 127.0.0.1" in text and f"XDG_CONFIG_HOME={tmp_path / 'config'}" in text
    assert json.loads((tmp_path / "config" / "rerun" / "analytics.json").read_text())["analytics_enabled"] is False
    said = subprocess.run([str(script), "analytics", "config"], capture_output=True, text=True, timeout=60,
                          check=True).stdout  # the launcher's own configuration, as the viewer reads it
    assert json.loads(said)["analytics_enabled"] is False
