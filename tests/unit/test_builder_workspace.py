"""The builder image's cargo workspace (images/builder/rust) compiles zenohd and the bridge's
Zenoh port in one build: it must stay zenohd's own lockfile plus the port, with the port's
profile and one zenoh version everywhere (else cargo would compile zenoh twice again, or the
port would be built with settings other than its own)."""
from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]
WORKSPACE = REPO / "images" / "builder" / "rust"
PORT = REPO / "firmware" / "ports" / "linux" / "zenoh_rust"
# zenohd 1.10.2's Cargo.toml: [dependencies.zenoh] features
ZENOHD_ZENOH_FEATURES = {"internal", "plugins", "runtime_plugins", "unstable"}


def test_profile_is_the_ports_own():
    ws = tomllib.loads((WORKSPACE / "Cargo.toml").read_text())
    port = tomllib.loads((PORT / "Cargo.toml").read_text())
    assert ws["profile"]["release"] == port["profile"]["release"]
    assert sorted(ws["workspace"]["members"]) == ["zenohd", "zn_port_zenoh"]


def test_one_zenoh_and_the_routers_version_everywhere():
    lock = tomllib.loads((WORKSPACE / "Cargo.lock").read_text())["package"]
    versions = {}
    for p in lock:
        versions.setdefault(p["name"], set()).add(p["version"])
    zenohd = re.search(r"^ZENOHD_VERSION := (\S+)", (REPO / "Makefile").read_text(), re.M).group(1)
    dockerfile = (REPO / "images" / "builder" / "Dockerfile").read_text()
    assert f"ARG ZENOHD_VERSION={zenohd}" in dockerfile
    assert versions["zenohd"] == versions["zenoh"] == {zenohd}
    port_dep = tomllib.loads((PORT / "Cargo.toml").read_text())["dependencies"]["zenoh"]
    port_dep = port_dep if isinstance(port_dep, dict) else {"version": port_dep}
    assert port_dep["version"] == f"={zenohd}"
    # features zenohd 1.10.2 itself enables on zenoh: asking for one of them adds nothing to the
    # workspace's unified feature set, so zenoh still compiles once for both
    assert set(port_dep.get("features", [])) <= ZENOHD_ZENOH_FEATURES
    port = next(p for p in lock if p["name"] == "zn_port_zenoh")
    assert port["dependencies"] == ["zenoh"]
