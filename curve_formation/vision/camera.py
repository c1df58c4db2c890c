"""A pinhole camera above the arena, and the floor homography it induces.

Arena frame: metres, z up, the floor at z = 0. Pixel coordinates: (u, v) with the origin at
the centre of the top-left pixel, u to the right, v down (OpenCV's convention).
"""

from dataclasses import dataclass
import math

import numpy as np


@dataclass(frozen=True)
class PinholeCamera:
    """K (3x3, pixels), R (3x3) and t (3,) mapping arena points X to camera R X + t."""

    width: int
    height: int
    K: np.ndarray   # noqa: N815 - the usual names
    R: np.ndarray   # noqa: N815
    t: np.ndarray

    def floor_homography(self, z=0.0):
        """3x3 H with (u, v, 1) ~ H (x, y, 1) for arena points on the plane at height z (m)."""
        return self.K @ np.column_stack([self.R[:, 0], self.R[:, 1], self.R[:, 2] * z + self.t])

    def project(self, points, z=0.0):
        """(k, 2) pixel positions of (k, 2) arena points at height z."""
        return apply_homography(self.floor_homography(z), points)


def overhead_camera(arena_size, resolution, tilt_deg=0.0, distance=2.0, margin_px=20):
    """A camera looking at the arena centre from `distance` (m), tilted by `tilt_deg` about
    the arena's x axis (towards -y), with a focal length that fits the whole arena in the
    frame with `margin_px` to spare. Straight down, arena x runs along u and y against v.
    """
    width, height = resolution
    tilt = math.radians(tilt_deg)
    # Straight down: camera x = arena x, camera y = -arena y, optical axis = -z.
    down = np.diag([1.0, -1.0, -1.0])
    c, s = math.cos(tilt), math.sin(tilt)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    rotation = rx @ down
    axis = rotation.T @ np.array([0.0, 0.0, 1.0])      # optical axis in the arena frame
    centre = np.array([arena_size[0] / 2, arena_size[1] / 2, 0.0])
    position = centre - distance * axis
    t = -rotation @ position
    corners = np.array([[0, 0, 0], [arena_size[0], 0, 0], [arena_size[0], arena_size[1], 0],
                        [0, arena_size[1], 0]], float)
    cam = (rotation @ corners.T).T + t
    normalised = cam[:, :2] / cam[:, 2:3]
    f = min((width / 2 - margin_px) / np.abs(normalised[:, 0]).max(),
            (height / 2 - margin_px) / np.abs(normalised[:, 1]).max())
    k = np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])
    return PinholeCamera(width, height, k, rotation, t)


def apply_homography(h, points):
    """(k, 2) points mapped by the 3x3 homography h."""
    points = np.asarray(points, float).reshape(-1, 2)
    mapped = np.column_stack([points, np.ones(len(points))]) @ np.asarray(h).T
    return mapped[:, :2] / mapped[:, 2:3]


def raised_plane_homography(to_plane, k, dz):
    """Pixel -> arena (x, y) homography of the plane dz (m) above the plane that the pixel ->
    arena homography `to_plane` maps (pixels undistorted, K the camera matrix).

    The camera's pose follows from K and the plane's homography: K^-1 to_plane^-1 is
    [r1 r2 t] up to scale, with its sign set so that the plane lies in front of the camera;
    the raised plane's homography is K [r1 r2 dz r3 + t] with r3 = r1 x r2 (z up).
    """
    m = np.linalg.solve(np.asarray(k, float), np.linalg.inv(np.asarray(to_plane, float)))
    scale = 2.0 / (np.linalg.norm(m[:, 0]) + np.linalg.norm(m[:, 1]))
    if m[2, 2] < 0:   # the plane's origin must have a positive depth
        scale = -scale
    r1, r2, t = m[:, 0] * scale, m[:, 1] * scale, m[:, 2] * scale
    r3 = np.cross(r1, r2)
    r3 /= np.linalg.norm(r3)
    return np.linalg.inv(np.asarray(k, float) @ np.column_stack([r1, r2, dz * r3 + t]))
