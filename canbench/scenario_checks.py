"""The bench's checks against one scenario run, one test per check (canbench/checks.py holds
the logic), collected by `pytest --pyargs canbench.scenario_checks` with the plugin's options
(canbench.pytest_plugin). Each failure says which frames failed and where they came from
(can.log:line)."""
from __future__ import annotations

import pytest

from .checks import CHECKS, skip_reason


@pytest.mark.parametrize("check", list(CHECKS))
def test_check(scenario_run, check):
    problems = CHECKS[check](scenario_run)
    if problems is None:
        pytest.skip(skip_reason(scenario_run, check))
    assert not problems, "\n".join(problems)
