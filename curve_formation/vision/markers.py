"""ArUco markers on robots and on the arena floor: ids, sizes and corner geometry.

Arena frame: metres, x to the right and y up seen from above, headings in radians from x.
A robot's marker lies flat with its x axis (from its corner 0 to corner 1, as cv2.aruco orders
corners) along the robot's heading; its centre sits at `offset` (robot frame, x forward) from
the axle centre. Corner markers lie with their x axis along the arena's x axis.
"""

from dataclasses import dataclass
import math

import cv2
import numpy as np


# cv2.aruco also has lower-case aliases (DICT_APRILTAG_36h11); the upper-case names suffice.
DICTIONARIES = tuple(sorted(name for name in dir(cv2.aruco)
                            if name.startswith('DICT_') and name == name.upper()))
# Unit square in ArUco corner order (top-left, top-right, bottom-right, bottom-left as seen
# in the marker image), in the marker's own frame: x along the marker's x axis, y to its top.
_UNIT = np.array([[-0.5, 0.5], [0.5, 0.5], [0.5, -0.5], [-0.5, -0.5]])


def dictionary(name):
    """The predefined cv2.aruco dictionary called `name` (e.g. 'DICT_4X4_50')."""
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


def dictionary_size(name):
    """Number of marker ids in a predefined dictionary."""
    return len(dictionary(name).bytesList)


def marker_bits(name):
    """Data bits per side of the dictionary's markers (4 for DICT_4X4_50)."""
    return dictionary(name).markerSize


def marker_corners(x, y, heading, side):
    """(4, 2) corners (m, arena frame) of a square of `side` (m) centred at (x, y)."""
    c, s = math.cos(heading), math.sin(heading)
    local = _UNIT * side
    return np.column_stack([x + c * local[:, 0] - s * local[:, 1],
                            y + s * local[:, 0] + c * local[:, 1]])


def pose_from_corners(corners, offset):
    """Axle-centre pose (x, y, heading) from a robot marker's 4 corners in the arena frame.

    The centre is where the diagonals cross; the heading is the mean direction of all four
    edges (the two along the marker's x axis, and the two along its y axis turned by -90
    degrees). offset: marker centre from the axle centre (robot frame).
    """
    p0, p1, p2, p3 = np.asarray(corners, float)
    centre = _diagonal_crossing(p0, p2, p1, p3)
    up = (p0 - p3) + (p1 - p2)
    along = (p1 - p0) + (p2 - p3) + np.array([up[1], -up[0]])
    heading = math.atan2(along[1], along[0])
    c, s = math.cos(heading), math.sin(heading)
    return (centre[0] - (c * offset[0] - s * offset[1]),
            centre[1] - (s * offset[0] + c * offset[1]), heading)


def robot_marker_pose(x, y, heading, offset):
    """Centre (x, y) of the marker of a robot at axle pose (x, y, heading)."""
    c, s = math.cos(heading), math.sin(heading)
    return x + c * offset[0] - s * offset[1], y + s * offset[0] + c * offset[1]


def _diagonal_crossing(a, b, c, d):
    """Intersection of lines a-b and c-d (falls back to the mean of the four points)."""
    r, s = b - a, d - c
    denom = r[0] * s[1] - r[1] * s[0]
    if abs(denom) < 1e-12:
        return (a + b + c + d) / 4
    t = ((c[0] - a[0]) * s[1] - (c[1] - a[1]) * s[0]) / denom
    return a + t * r


@dataclass(frozen=True)
class MarkerLayout:
    """Which marker is where: built from an experiment's `camera` section.

    robot_ids[i]: marker id of agent i + 1. corners: {id: (x, y)} centres (m). Heights (m)
    above the floor of the robots' markers and of the corner markers.
    """

    dictionary_name: str
    robot_ids: tuple
    marker_size: float
    marker_offset: tuple
    corners: dict
    corner_size: float
    marker_height: float = 0.0
    corner_height: float = 0.0

    @classmethod
    def from_spec(cls, camera):
        return cls(camera.dictionary, tuple(camera.robot_ids), camera.marker_size,
                   tuple(camera.marker_offset), {c.id: tuple(c.position) for c in camera.corners},
                   camera.corner_size, camera.marker_height, camera.corner_height)

    @property
    def agent_of(self):
        """{marker id: agent index (1-based)}."""
        return {m: i + 1 for i, m in enumerate(self.robot_ids)}

    def body_radius(self, radius=0.0):
        """The radius (m) of a robot's body: `radius` (robots.radius) when given, else a disc
        just larger than the marker with its quiet zone.
        """
        return radius or 0.8 * self.marker_size * math.sqrt(2)

    def corner_reach(self):
        """Distance (m) from a corner marker's centre to the far corner of its quiet zone."""
        bits = marker_bits(self.dictionary_name)
        return 0.5 * math.sqrt(2) * self.corner_size * (bits + 4) / (bits + 2)

    def corner_points(self, ids):
        """(4 k, 2) arena corners (m) of the corner markers `ids`, in cv2.aruco order."""
        return np.concatenate([marker_corners(self.corners[i][0], self.corners[i][1], 0.0,
                                              self.corner_size) for i in ids])
