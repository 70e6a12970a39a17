"""Every repository path README.md and docs/*.md name exists: a word with a slash whose first part
is a top-level entry of the repository (generated places, build/ and reports/, and placeholders
like <run-id> aside; globs must match something), in code spans, links and prose alike."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit
REPO = Path(__file__).resolve().parents[2]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
GENERATED = {"build", "reports"}  # written by builds and runs, not part of the tree
EXAMPLES = {"scenarios/my-drive.yaml", "scenarios/traces/drive.log",  # what README's walkthrough writes
            "scenarios/x.yaml"}  # an error message README shows
PATH = re.compile(r"[\w.\-*]+(?:/[\w.\-*]+)+/?|[\w.\-*]+/")


def named_paths(doc: Path):
    """(line, path) of every repository path the document names."""
    top = {p.name for p in REPO.iterdir()} - GENERATED
    for n, line in enumerate(doc.read_text().splitlines(), 1):
        for word in re.split(r"[\s,;:()\[\]'\"=`|]+", line):
            word = word.rstrip(".")
            if "<" in word or "$" in word or word.startswith(("/", "~", "http")) or not PATH.fullmatch(word):
                continue
            if word.split("/")[0] in top and word not in EXAMPLES:
                yield n, word


def exists(path: str, base: Path) -> bool:
    for root in (REPO, base):
        if any(ch in path for ch in "*?"):
            if list(root.glob(path)):
                return True
        elif (root / path).exists():
            return True
    return False


@pytest.mark.parametrize("doc", DOCS, ids=[d.name for d in DOCS])
def test_every_named_path_exists(doc):
    missing = [f"{doc.relative_to(REPO)}:{n}: {p}" for n, p in named_paths(doc) if not exists(p, doc.parent)]
    assert not missing, "\n".join(missing)
