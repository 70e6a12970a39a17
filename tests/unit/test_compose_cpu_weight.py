"""The bench's reference (the bus and every emulated ECU) gets the larger CPU weight in every
shipped scenario's compose set, and nothing else does: the stimulus keeps to its trace on a
busy machine and the bridge under test gets no advantage (canbench.compose.REFERENCE_CPU_SHARES)."""
from __future__ import annotations

import pytest
from test_compose_privileges import merged, override_of, variants

from canbench import compose

pytestmark = pytest.mark.unit


@pytest.mark.parametrize(("path", "viewer", "mode"), variants())
def test_the_bus_and_the_ecus_go_first(path, viewer, mode):
    services = merged(override_of(path, viewer, mode))["services"]
    weighted = {name for name, svc in services.items() if "cpu_shares" in svc}
    ecus = {name for name in services if name.startswith("ecu-")}
    assert weighted == {"bus", *ecus}
    assert all(services[name]["cpu_shares"] == compose.REFERENCE_CPU_SHARES for name in weighted)
