"""make check runs tests/unit with -m unit: a test file here without the unit mark would never
run (six such files, 208 tests, had not run in make check until 2026-12-05)."""
from __future__ import annotations

from pathlib import Path

import pytest

pytestmark = pytest.mark.unit


def test_every_test_file_here_is_marked_unit():
    files = sorted(Path(__file__).parent.glob("test_*.py"))
    unmarked = [p.name for p in files if "pytest.mark.unit" not in p.read_text()]
    assert unmarked == []
