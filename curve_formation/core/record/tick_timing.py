"""Whether a run's controllers kept their rate: from the times each robot's commands were
published (one per control tick) and received, its achieved rate, missed ticks, period
jitter and command age. What metrics.json's `ticks`, the report and the runner's status line
say.

Times in s on one clock (the DDS source and reception timestamps, system time).
"""

from typing import Any

import numpy as np
from numpy.typing import ArrayLike


KEPT_RATE = 0.95   # a controller below this share of its rate did not keep it


def tick_timing(published: ArrayLike, received: ArrayLike, rate_hz: float
                ) -> dict[str, Any] | None:
    """One controller's timing from its commands' publication and reception times (s):
    achieved rate (Hz, ticks over the time they span), missed ticks (each gap of g periods
    misses round(g) - 1), period jitter p50 and p99 (ms, |gap - period|) and command age p50
    and p99 (ms, reception - publication); None with fewer than two commands.
    """
    sent = np.asarray(published, dtype=float)
    got = np.asarray(received, dtype=float)
    if sent.size < 2:
        return None
    period = 1.0 / rate_hz
    gaps = np.diff(sent)
    span = float(sent[-1] - sent[0])
    missed = int(np.maximum(np.round(gaps / period) - 1.0, 0.0).sum())
    jitter = np.abs(gaps - period) * 1e3
    age = (got - sent) * 1e3
    return {'ticks': int(sent.size), 'rate_hz': round((sent.size - 1) / span, 3)
            if span > 0 else None, 'missed_ticks': missed,
            'jitter_ms_p50': round(float(np.percentile(jitter, 50)), 2),
            'jitter_ms_p99': round(float(np.percentile(jitter, 99)), 2),
            'command_age_ms_p50': round(float(np.percentile(age, 50)), 2),
            'command_age_ms_p99': round(float(np.percentile(age, 99)), 2)}


def run_timing(arrivals: dict[int, tuple[ArrayLike, ArrayLike]], rate_hz: float
               ) -> dict[str, Any]:
    """Every controller's tick_timing ({robot: (published, received)}), the slowest one and
    the robots whose controllers fell below KEPT_RATE of rate_hz.
    """
    robots = {robot: timing for robot, (sent, got) in sorted(arrivals.items())
              if (timing := tick_timing(sent, got, rate_hz)) is not None}
    rated = {robot: t['rate_hz'] for robot, t in robots.items() if t['rate_hz'] is not None}
    slowest = min(rated, key=lambda robot: rated[robot]) if rated else None
    return {'rate_hz': rate_hz,
            'robots': {f'robot_{robot}': timing for robot, timing in robots.items()},
            'slowest': None if slowest is None else {'robot': slowest,
                                                     'rate_hz': rated[slowest]},
            'below_rate': [robot for robot, rate in rated.items()
                           if rate < KEPT_RATE * rate_hz],
            'jitter_ms_p99_worst': max((t['jitter_ms_p99'] for t in robots.values()),
                                       default=None)}
