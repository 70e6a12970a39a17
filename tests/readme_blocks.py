"""What the README tests share (tests/unit/test_readme.py, tests/compose/test_readme.py): the
commands of a README block, a fresh clone of this checkout, and PATH as on a fresh machine."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def readme_block(heading: str) -> list[str]:
    """The commands of the first sh block under a README heading, comments stripped."""
    text = (REPO / "README.md").read_text()
    section = text.split(f"\n## {heading}\n", 1)[1]
    block = re.search(r"```sh\n(.*?)```", section, re.S)
    assert block, f"README: no sh block under '## {heading}'"
    return [line.split("#", 1)[0].strip() for line in block.group(1).splitlines() if line.split("#", 1)[0].strip()]


def fresh_clone(tmp_path: Path) -> Path:
    """git clone of this checkout, with its uncommitted changes laid over (what is tested is
    what is here), no build products, no .venv, no reports; a shipped trace as drive.log."""
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", str(REPO), str(clone)], check=True, timeout=120)
    changed = subprocess.run(["git", "ls-files", "-m", "-o", "--exclude-standard"], cwd=REPO, check=True,
                             capture_output=True, text=True).stdout.split()
    for name in changed:
        if (REPO / name).is_file():
            (clone / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / name, clone / name)
        elif (clone / name).exists():
            (clone / name).unlink()
    shutil.copy(REPO / "scenarios" / "traces" / "powertrain-2s.log", clone / "drive.log")
    return clone


def path_without_canbench() -> str:
    """PATH as on a fresh machine: no canbench installed anywhere (it is, here, by pip)."""
    return os.pathsep.join(d for d in os.environ["PATH"].split(os.pathsep) if not (Path(d) / "canbench").exists())
