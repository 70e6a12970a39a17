"""Bounded distributions for the oracle (latency per direction, cycle time per id): every value
kept exactly up to a stated number, then a log-bucket sketch with a stated error, so an
hour-long run's analysis needs no more memory than a minute's. count, min and max stay exact.

Exact mode gives the bench's nearest-rank percentiles (canbench.stats) of the very values.
Sketch mode: buckets SKETCH_GROWTH wide in ratio (1 %) from SKETCH_FLOOR_MS (0.1 us) up; a
percentile is its bucket's geometric middle, within 0.5 % of the nearest-rank value, clamped
to [min, max]; values below the floor (zero, negatives: a bench error, reported apart) read as
the floor or the minimum. `values` then holds a uniform sample (reservoir, fixed seed) of
`cap` of them, for plots."""
from __future__ import annotations

import bisect
import math
import random
from array import array

from .stats import latency_stats

EXACT_VALUES = 1 << 20     # values kept exactly per latency distribution (float64: 8 MiB)
SKETCH_GROWTH = 1.01       # ratio between a sketch bucket's bounds: percentiles within 0.5 %
SKETCH_FLOOR_MS = 1e-4     # values below it share bucket 0
FOLD = 1 << 16             # values buffered (sketch mode) before they are folded into the sketch
_LOG_GROWTH = math.log(SKETCH_GROWTH)
_SCALE = 1 / _LOG_GROWTH
_SHIFT = 1 - math.log(SKETCH_FLOOR_MS) * _SCALE  # bucket of v >= floor: int(log(v) * _SCALE + _SHIFT)
_log = math.log


class Distribution:
    """Values (ms) added one at a time; memory bounded by `cap` values, a buffer of FOLD values
    and the sketch (at most ~2600 buckets: 0.1 us to 10^7 ms at 1 %)."""

    __slots__ = ("values", "cap", "count", "low", "high", "sketch", "sample", "_buffer", "_rng", "_w", "_next")

    def __init__(self, cap: int | None = None, sample: bool = True):
        """sample: past cap, keep a uniform sample of cap values (else the first cap of them)."""
        self.values = array("d")
        self.cap = EXACT_VALUES if cap is None else cap
        self.sample = sample
        self.count = 0            # sketch mode: values folded into the sketch
        self.low = math.inf
        self.high = -math.inf
        self.sketch: dict[int, int] | None = None   # bucket -> count, once past cap
        self._buffer = array("d")  # values not yet folded into the sketch
        self._rng = random.Random(0)
        self._w = 0.0
        self._next = 0

    def add(self, v: float) -> None:
        """Exact mode is values.append (callers on a hot path inline it while len(values) < cap)."""
        if self.sketch is None:
            if len(self.values) < self.cap:
                self.values.append(v)
                return
            self._start_sketch()
        self._buffer.append(v)
        if len(self._buffer) >= FOLD:
            self._fold()

    def _start_sketch(self) -> None:
        self.sketch = {}
        for at in range(0, len(self.values), FOLD):  # FOLD at a time: sorting them all would need 32 B a value
            self._count(self.values[at:at + FOLD])
        # the exact values stay, as the sample's first cap values
        self._w = math.exp(math.log(1 - self._rng.random()) / self.cap)
        self._next = self.cap + self._skip()

    def _count(self, values: array) -> None:
        """Into the sketch, sorted: one log per bucket, not per value."""
        sketch = self.sketch
        assert sketch is not None
        ordered = sorted(values)
        if not ordered:
            return
        self.low = min(self.low, ordered[0])
        self.high = max(self.high, ordered[-1])
        n = len(ordered)
        i = bisect.bisect_left(ordered, SKETCH_FLOOR_MS)
        if i:
            sketch[0] = sketch.get(0, 0) + i
        while i < n:
            b = int(_log(ordered[i]) * _SCALE + _SHIFT)
            j = max(i + 1, bisect.bisect_left(ordered, SKETCH_FLOOR_MS * SKETCH_GROWTH ** b, i))
            sketch[b] = sketch.get(b, 0) + j - i
            i = j
        self.count += n

    def _fold(self) -> None:
        """The buffer into the sketch and into the uniform sample (Vitter's algorithm L: random
        draws per value taken into the sample, not per value)."""
        buffer = self._buffer
        self._buffer = array("d")
        first = self.count
        self._count(buffer)
        if not self.sample:
            return
        rng, cap, values = self._rng, self.cap, self.values
        while self._next < self.count:
            values[rng.randrange(cap)] = buffer[self._next - first]
            self._w *= math.exp(math.log(1 - rng.random()) / cap)
            self._next += self._skip() + 1

    def _skip(self) -> int:
        gap = 1 - self._w
        return int(math.log(1 - self._rng.random()) / math.log(gap)) if 0 < gap < 1 else 0

    @staticmethod
    def _bucket(v: float) -> int:
        return 0 if v < SKETCH_FLOOR_MS else int(_log(v) * _SCALE + _SHIFT)

    @property
    def exact(self) -> bool:
        return self.sketch is None

    def __len__(self) -> int:
        return len(self.values) if self.sketch is None else self.count + len(self._buffer)

    def percentile(self, q: float) -> float | None:
        """Nearest rank, as canbench.stats.percentile (exact mode: the very value)."""
        if self.sketch is None:
            if not self.values:
                return None
            ordered = sorted(self.values)
            return ordered[min(len(ordered) - 1, int(round(q * (len(ordered) - 1))))]
        if self._buffer:
            self._fold()
        rank = min(self.count - 1, int(round(q * (self.count - 1))))
        seen = 0
        for b in sorted(self.sketch):
            seen += self.sketch[b]
            if seen > rank:
                mid = SKETCH_FLOOR_MS if b == 0 else SKETCH_FLOOR_MS * SKETCH_GROWTH ** (b - 0.5)
                return min(self.high, max(self.low, mid))
        return self.high

    def stats(self) -> dict:
        """count, min, p50, p90, p99, max (ms), as canbench.stats.latency_stats."""
        if self.sketch is None:
            return latency_stats(self.values)
        if self._buffer:
            self._fold()
        return {"count": self.count, "min_ms": self.low, "p50_ms": self.percentile(0.5),
                "p90_ms": self.percentile(0.9), "p99_ms": self.percentile(0.99), "max_ms": self.high}
