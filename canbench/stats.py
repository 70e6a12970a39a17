"""Statistics the bench reports: percentiles and latency summaries (nearest rank, as
every report and gate of the bench computes them)."""
from __future__ import annotations

from collections.abc import Sequence


def percentile(values: Sequence[float], q: float) -> float | None:
    """The value at rank round(q * (n - 1)) of the sorted values; None for no values."""
    if not values:
        return None
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q * (len(ordered) - 1))))]


def latency_stats(values_ms: Sequence[float]) -> dict:
    """count, min, p50, p90, p99, max (ms) of a latency distribution; None where empty."""
    if not values_ms:
        return {"count": 0, "min_ms": None, "p50_ms": None, "p90_ms": None, "p99_ms": None, "max_ms": None}
    ordered = sorted(values_ms)

    def at(q: float) -> float:
        return ordered[min(len(ordered) - 1, int(round(q * (len(ordered) - 1))))]
    return {"count": len(ordered), "min_ms": ordered[0], "p50_ms": at(0.5), "p90_ms": at(0.9),
            "p99_ms": at(0.99), "max_ms": ordered[-1]}
