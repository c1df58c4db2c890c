"""Robots as bodies: discs that cannot overlap, in an arena whose walls they cannot cross.

Frames and units: poses (n, 3) x, y, theta in the arena frame (m, rad); a body is a disc of
`radius` (m) around the axle centre; the arena is [0, width] x [0, height] (m); width or
height <= 0 means no walls. Contacts are resolved by moving bodies apart (position-based, as
equal robots push each other: each of a touching pair gives way by half the overlap), and a
body that went through a wall is put back against it. Headings are left alone.

Scalar loops only, so that the same source runs compiled (core.base.jit) in the batch simulator and
in the kinematic world of the fake_arena node and the tick pipeline: one rule for contacts and
one tally of them.
"""

import math
from typing import NamedTuple

import numpy as np

from curve_formation.core.base.shapes import BoolArray, FloatArray


# Passes over all pairs per resolution: a chain of pushed bodies settles within a few.
CONTACT_PASSES = 4
# Two surfaces this close (m) are touching: what resolution leaves behind is exactly 0.
TOUCHING = 1e-9


def separate(poses: FloatArray, radius: float, width: float, height: float,
             touching: BoolArray) -> tuple[int, bool, float]:
    """Resolve contacts in place; returns (new contacts, touching now, smallest gap).

    poses (n, 3): moved so that no two discs of `radius` overlap and none crosses a wall.
    touching (n, n) bool: which pairs touched after the previous call; updated. New contacts
    counts the pairs that touch now and did not before; touching now is whether any pair
    touches; the smallest gap (m) is the smallest distance between two surfaces before the
    resolution (negative: they overlapped).
    """
    n = poses.shape[0]
    contact = (2.0 * radius + TOUCHING) ** 2
    nearest = math.inf
    any_contact = False
    for i in range(n):
        for j in range(i + 1, n):
            d2 = (poses[i, 0] - poses[j, 0]) ** 2 + (poses[i, 1] - poses[j, 1]) ** 2
            nearest = min(nearest, d2)
            if d2 <= contact or touching[i, j]:
                any_contact = True
    walls = False
    for i in range(n):
        walls = _inside_walls(poses, i, radius, width, height) or walls
    smallest = math.sqrt(nearest) - 2.0 * radius
    if not any_contact:
        return 0, False, smallest
    for _ in range(CONTACT_PASSES):
        moved = False
        for i in range(n):
            for j in range(i + 1, n):
                dx = poses[i, 0] - poses[j, 0]
                dy = poses[i, 1] - poses[j, 1]
                dist = math.hypot(dx, dy)
                overlap = 2 * radius - dist
                if overlap <= 0.0:
                    continue
                if dist > 0.0:
                    ux, uy = dx / dist, dy / dist
                else:   # on top of each other: part them along x
                    ux, uy = 1.0, 0.0
                poses[i, 0] += 0.5 * overlap * ux
                poses[i, 1] += 0.5 * overlap * uy
                poses[j, 0] -= 0.5 * overlap * ux
                poses[j, 1] -= 0.5 * overlap * uy
                moved = True
        for i in range(n):
            moved = _inside_walls(poses, i, radius, width, height) or moved
        if not moved:
            break
    new = 0
    now = False
    for i in range(n):
        for j in range(i + 1, n):
            gap = math.hypot(poses[i, 0] - poses[j, 0], poses[i, 1] - poses[j, 1]) - 2 * radius
            touch = gap <= TOUCHING
            if touch and not touching[i, j]:
                new += 1
            touching[i, j] = touch
            now = now or touch
    return new, now, smallest


class Contacts(NamedTuple):
    """Bodies (robots.radius, m; 0: points that pass through each other) in the arena
    (width, height, m; <= 0: no walls), and the running tally of their contacts: touching
    (n, n) bool, and tally [new contacts, time with a contact (s), smallest surface gap (m)].
    """

    radius: float
    width: float
    height: float
    touching: BoolArray
    tally: FloatArray


def contacts_of(n: int, radius: float, width: float, height: float) -> Contacts:
    """A tally of nothing yet for n bodies."""
    return Contacts(float(radius), float(width), float(height), np.zeros((n, n), bool),
                    np.array([0.0, 0.0, math.inf]))


def touch(poses: FloatArray, contacts: 'Contacts', step: float) -> float:
    """Resolve contacts after a step of `step` s (bodies only: radius > 0) and keep the tally;
    the smallest gap between two surfaces (m; -inf while two touch).
    """
    if contacts.radius <= 0.0:
        return math.inf
    new, now, gap = separate(poses, contacts.radius, contacts.width, contacts.height,
                             contacts.touching)
    contacts.tally[0] += new
    if now:
        contacts.tally[1] += step
    contacts.tally[2] = min(contacts.tally[2], gap)
    return -math.inf if now else gap


def contact_summary(contacts: Contacts) -> dict[str, float | int | None]:
    """{'count', 'time' (s), 'smallest_gap' (m, None without bodies)} of the tally so far."""
    new, time, gap = contacts.tally
    return {'count': int(new), 'time': float(time),
            'smallest_gap': float(gap) if contacts.radius > 0 and math.isfinite(gap) else None}


def _inside_walls(poses: FloatArray, i: int, radius: float, width: float, height: float
                  ) -> bool:
    """Put body i back inside the walls; True if it had to move."""
    moved = False
    if width > 0.0:
        x = min(max(poses[i, 0], radius), width - radius)
        moved = x != poses[i, 0]
        poses[i, 0] = x
    if height > 0.0:
        y = min(max(poses[i, 1], radius), height - radius)
        moved = moved or y != poses[i, 1]
        poses[i, 1] = y
    return moved
