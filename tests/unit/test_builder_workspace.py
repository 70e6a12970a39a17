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
    # the port's zenoh features are the build's (zenohd's defaults are off): zenoh's own defaults
    # (every link protocol: 75 crates more) must not come back through the port
    assert port_dep.get("default-features") is False
    # and zenoh's own crates the port uses directly (its buffers: a put's reused buffers; its
    # transport: held direct writes), at the same version, asking no feature of their own: what
    # zenoh gives them, so nothing compiles twice
    own = ("zenoh-buffers", "zenoh-transport")
    deps = tomllib.loads((PORT / "Cargo.toml").read_text())["dependencies"]
    for crate in own:
        assert deps[crate] == {"version": f"={zenohd}", "default-features": False}, crate
        assert versions[crate] == {zenohd}, crate
    port = next(p for p in lock if p["name"] == "zn_port_zenoh")
    assert port["dependencies"] == ["zenoh", *own]


def test_every_workspace_build_leaves_zenohds_defaults_off_and_zn_flood_adds_no_feature():
    """cargo unifies features over one build: a build line without --no-default-features turns
    zenohd's default (all of zenoh's links) back on, and a zn-flood asking for more than the port
    would change the feature set the bench image builds with: zenoh would compile again."""
    for image in ("builder", "bench"):
        dockerfile = (REPO / "images" / image / "Dockerfile").read_text()
        builds = re.findall(r"cargo build [^\n]*", dockerfile)
        assert builds, image
        for line in builds:
            assert "--workspace --no-default-features" in line, (image, line)
    port = tomllib.loads((PORT / "Cargo.toml").read_text())["dependencies"]["zenoh"]
    flood = tomllib.loads((REPO / "bench" / "tools" / "zn-flood" / "Cargo.toml").read_text())["dependencies"]["zenoh"]
    assert flood.get("default-features") is False
    assert set(flood.get("features", [])) <= set(port["features"])
