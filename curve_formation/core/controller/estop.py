"""The e-stop as every node that acts on it holds it: latched where it acts.

An e-stop command (engage or release) may come from anyone; each node that can move a robot
(controller, robot bridge, fake robot or arena) and the curve server keeps the last state it
was commanded, whether or not the sender is still there, and announces it to the others. A
node that starts while the formation is stopped learns it from them (`EstopLatch.peer`).

Rules (all times in s):
- An engage command always engages.
- A release command releases unless it was sent before the newest engage this node applied
  (`sent_at`, the sender's clock): a release delayed behind a later stop (a retransmission,
  a second path) must not undo that stop. Clocks that disagree can only make a release be
  ignored, never a stop.
- A peer's engaged state, held for a stop sent at `since`, engages this node when that stop is
  newer than every command this node applied: the formation passes a stop on from whichever
  node got it first (and a node that starts while the formation is stopped learns it), while
  a peer still announcing an old stop cannot undo a newer release. A peer's release never
  releases anyone: only a release command does.
"""

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
import math
from typing import NamedTuple


class EstopReport(NamedTuple):
    """A node's announced e-stop state (on /formation/estop_state)."""

    holder: str      # the node's fully qualified name
    role: str        # what it is: its node name ('formation_controller', 'robot_bridge', ...)
    robot: str       # the robot it acts for ('robot_3'), '' for none (the curve server)
    engaged: bool
    by: str          # who sent the command it holds ('' before any)
    since: float     # when that command was sent (s, its sender's clock; -inf before any)
    robots: int      # agents in the formation as the node knows it (0: does not know)
    holders: int = 0   # e-stop holders it hears announce, itself included (0: not told)


def estop_fields(engaged: bool, role: str, by: str, since: float, robots: int,
                 holders: int = 0) -> dict[str, str]:
    """The key/value text fields an EstopReport travels as (a DiagnosticStatus's values)."""
    return {'engaged': 'true' if engaged else 'false', 'role': role, 'by': by,
            'since': repr(float(since)), 'robots': str(int(robots)),
            'holders': str(int(holders))}


def parse_report(holder: str, robot: str, values: Mapping[str, str]) -> EstopReport:
    """EstopReport from a holder's name, robot and text fields (estop_fields); ValueError
    naming what is wrong when they are not an e-stop state.
    """
    engaged = values.get('engaged')
    robots = values.get('robots', '0')
    holders = values.get('holders', '0')
    try:
        since = float(values.get('since', '-inf')[:40])
    except ValueError:
        since = math.nan
    if (engaged not in ('true', 'false') or not holder or not robots.isdigit()
            or len(robots) > 6 or math.isnan(since) or since == math.inf
            or not holders.isdigit() or len(holders) > 6):
        raise ValueError(f'not an e-stop state: name {holder[:80]!r}, engaged '
                         f'{str(engaged)[:20]!r}, since {str(values.get("since"))[:40]!r}, '
                         f'robots {robots[:20]!r}, holders {holders[:20]!r}')
    return EstopReport(holder, values.get('role', ''), robot, engaged == 'true',
                       values.get('by', ''), since, int(robots), int(holders))


@dataclass
class EstopLatch:
    """One node's e-stop state."""

    engaged: bool = False
    by: str = ''                  # who sent the command (or whose state was adopted)
    since: float = -math.inf      # send time of the command held (s, its sender's clock)
    newest: float = -math.inf         # send time of the newest command applied (s)
    newest_engage: float = -math.inf  # ... of the newest engage applied (s)

    def command(self, engaged: bool, sent_at: float, by: str, now: float) -> bool:
        """An engage (True) or release (False) sent at `sent_at` (s, sender's clock) by `by`,
        received at `now` (s, this node's clock). Returns whether the state changed.
        """
        if not math.isfinite(sent_at):
            sent_at = self.newest if engaged else -math.inf
        if engaged:
            self.newest_engage = max(self.newest_engage, sent_at)
        elif sent_at < self.newest_engage:
            return False   # a release older than the stop it would undo
        self.newest = max(self.newest, sent_at)
        return self._set(engaged, by, sent_at, now)

    def peer(self, engaged: bool, since: float, by: str, now: float) -> bool:
        """Another node's announced state, holding a command sent at `since` (s); adopted
        only as described in the module docstring. Returns whether the state changed.
        """
        if not engaged or not since > self.newest:
            return False
        self.newest = self.newest_engage = since
        return self._set(True, by, since, now)

    def _set(self, engaged: bool, by: str, since: float, now: float) -> bool:
        if engaged == self.engaged:
            self.since = max(self.since, since) if engaged else since
            return False
        self.engaged, self.by, self.since = engaged, by, since
        return True


def stopped_intervals(events: Iterable[tuple[float, str, bool]], end: float
                      ) -> list[tuple[float, float | None]]:
    """[(start, stop)] (s) during which some node held the e-stop engaged.

    events: [(t s, holder name, engaged bool)] in time order, each holder's announced state
    (repeats allowed); end: the run's last time (s). An interval still open at `end` has
    stop None.
    """
    held: set[str] = set()
    out: list[tuple[float, float | None]] = []
    start: float | None = None
    for t, holder, engaged in events:
        if engaged:
            held.add(holder)
        else:
            held.discard(holder)
        if held and start is None:
            start = t
        elif not held and start is not None:
            out.append((start, t))
            start = None
    if start is not None:
        out.append((start, None))
    return [(a, b) for a, b in out if a <= end]


def stopped_time(intervals: Iterable[tuple[float, float | None]], end: float) -> float:
    """Total time (s) in intervals (open ones counted until `end`)."""
    return sum((end if b is None else min(b, end)) - a for a, b in intervals if a < end)
