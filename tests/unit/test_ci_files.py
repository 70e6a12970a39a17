"""The nightly CI files users copy (.github/workflows/nightly.yml, .gitlab-ci.yml) pass their
CI system's JSON Schema (check-jsonschema's vendored copies) and do what README says: the
shard matrix agrees with SHARD=k/N, soak, bench, baselines kept and compared; every make
target they call exists."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]
GITHUB = REPO / ".github" / "workflows" / "nightly.yml"
GITLAB = REPO / ".gitlab-ci.yml"
SCHEMAS = {GITHUB: "vendor.github-workflows", GITLAB: "vendor.gitlab-ci"}


def schema_check(path: Path, schema: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "check_jsonschema", "--builtin-schema", schema, str(path)],
                          capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize("path", list(SCHEMAS), ids=lambda p: p.name)
def test_ci_file_passes_its_schema(path, tmp_path):
    proc = schema_check(path, SCHEMAS[path])
    assert proc.returncode == 0, proc.stdout + proc.stderr
    # the check is not vacuous: a misspelt key fails it
    broken = tmp_path / path.name
    broken.write_text(path.read_text().replace("timeout", "time-out", 1))
    assert schema_check(broken, SCHEMAS[path]).returncode != 0


def make_targets() -> set[str]:
    return set(re.findall(r"^([a-z][a-z0-9-]*):", (REPO / "Makefile").read_text(), re.M))


def commands(doc) -> list[str]:
    """Every shell command: GitHub's run (a string), GitLab's script (a list of strings)."""
    if isinstance(doc, dict):
        return [c for k, v in doc.items()
                for c in ([v] if k == "run" else v if k == "script" else commands(v))]
    if isinstance(doc, list):
        return [c for v in doc for c in commands(v)]
    return []


@pytest.mark.parametrize("path", list(SCHEMAS), ids=lambda p: p.name)
def test_ci_file_runs_existing_make_targets(path):
    text = "\n".join(commands(yaml.safe_load(path.read_text())))
    called = set(re.findall(r"\bmake ([a-z][a-z0-9-]*)", text))
    assert {"test", "soak", "bench", "venv"} <= called and called <= make_targets()
    assert "canbench suite compare" in text


def test_github_matrix_agrees_with_the_shard_count():
    wf = yaml.safe_load(GITHUB.read_text())
    shards = wf["jobs"]["test"]["strategy"]["matrix"]["shard"]
    run = " ".join(commands(wf["jobs"]["test"]))
    n = int(re.search(r"SHARD=\$\{\{ matrix\.shard \}\}/(\d+)", run).group(1))
    assert shards == list(range(1, n + 1))
    uploads = [s["with"]["name"] for s in wf["jobs"]["compare"]["steps"] if "upload-artifact" in s.get("uses", "")]
    assert uploads == ["baseline"] and "if" not in wf["jobs"]["compare"]["steps"][-1]  # kept only on success


def test_gitlab_shards_by_its_node_index():
    ci = yaml.safe_load(GITLAB.read_text())
    assert ci["test"]["parallel"] >= 2
    assert "make test SHARD=${CI_NODE_INDEX}/${CI_NODE_TOTAL} JOBS=2" in ci["test"]["script"]
    assert ci["test"]["artifacts"]["reports"]["junit"] == "reports/suite-*/junit.xml"
    assert ci["baseline"]["needs"] == ["test", "compare"]
