"""The patched zenoh crates (docs/upstream/README.md) are what every
Rust build of the bench uses: each is zenoh's pinned version with its patch from docs/upstream/
applied, taken by [patch.crates-io] in every workspace that builds zenoh, and locked as a path
package (a lockfile that still names the registry's crate would build the unpatched one, or fail
under --locked)."""
from __future__ import annotations

import shutil
import subprocess
import tomllib
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]
PORT = REPO / "firmware" / "ports" / "linux" / "zenoh_rust"
PATCHED = PORT / "patched"
# crate -> (its patches in the order they apply, the path components above the crate in their file names)
PATCHES = {
    "zenoh-link-tls": (["docs/upstream/zenoh-link-tls-split-stream.patch"], 2),
    "zenoh-sync": (["docs/upstream/zenoh-sync-lifo-queue-notify-waiters.patch"], 3),
    "zenoh-transport": (["docs/upstream/zenoh-transport-lowlatency-buffered-read.patch",
                         "docs/upstream/zenoh-transport-universal-direct-write.patch",
                         "docs/upstream/zenoh-transport-universal-buffered-read.patch"], 3),
}
# workspace root -> the patched crates it uses (zn-flood speaks TCP only and receives nothing)
WORKSPACES = {
    PORT: set(PATCHES),
    REPO / "images" / "builder" / "rust": set(PATCHES),
    REPO / "bench" / "tools" / "zn-flood": {"zenoh-sync", "zenoh-transport"},
}


def zenoh_pin() -> str:
    return tomllib.loads((PORT / "Cargo.toml").read_text())["dependencies"]["zenoh"]["version"].lstrip("=")


def test_each_patched_crate_is_the_pinned_version():
    assert sorted(p.name for p in PATCHED.iterdir() if p.is_dir()) == sorted(PATCHES)
    for crate in PATCHES:
        package = tomllib.loads((PATCHED / crate / "Cargo.toml").read_text())["package"]
        assert (package["name"], package["version"]) == (crate, zenoh_pin()), \
            f"{crate}: re-run scripts/vendor-patched-crates after moving zenoh's pin"


@pytest.mark.skipif(shutil.which("patch") is None, reason="needs patch(1)")
@pytest.mark.parametrize("crate", sorted(PATCHES))
def test_each_patched_crate_holds_its_patch(crate, tmp_path):
    """Reversing the patches, last first, applies cleanly: the crate is the patches applied (and
    nothing else of them was undone by hand since)."""
    patches, strip = PATCHES[crate]
    copy = tmp_path / crate
    shutil.copytree(PATCHED / crate, copy)
    for patch in reversed(patches):
        r = subprocess.run(["patch", "-R", "-s", "-p", str(strip), "-d", str(copy), "-i", str(REPO / patch)],
                           capture_output=True, text=True)
        assert r.returncode == 0, f"{crate} does not hold {patch}: {r.stdout}{r.stderr}"


@pytest.mark.parametrize("root", sorted(WORKSPACES), ids=lambda p: str(p.relative_to(REPO)))
def test_every_workspace_takes_and_locks_them(root):
    manifest = tomllib.loads((root / "Cargo.toml").read_text())
    patches = manifest.get("patch", {}).get("crates-io", {})
    assert set(patches) == WORKSPACES[root]
    lock = {p["name"]: p for p in tomllib.loads((root / "Cargo.lock").read_text())["package"]}
    for crate, spec in patches.items():
        # the builder's path is where the image puts the port (images/builder/Dockerfile)
        where = Path(spec["path"].replace("zn_port_zenoh/", str(PORT.relative_to(REPO)) + "/"))
        target = (root / where) if (root / where).exists() else REPO / where
        assert target.resolve() == (PATCHED / crate).resolve(), (root, crate, spec)
        assert "source" not in lock[crate] and "checksum" not in lock[crate], \
            f"{root / 'Cargo.lock'} still locks the registry's {crate}"
        assert lock[crate]["version"] == zenoh_pin()


def test_the_builder_image_has_them_before_it_compiles_zenoh():
    dockerfile = (REPO / "images" / "builder" / "Dockerfile").read_text()
    copied = dockerfile.index("COPY firmware/ports/linux/zenoh_rust/patched /src/rust/zn_port_zenoh/patched")
    assert copied < dockerfile.index("cargo build")
