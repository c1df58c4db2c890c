"""A real lens in front of the pinhole: OpenCV's distortion model, for the fake camera.

The ideal frame of a PinholeCamera is rendered first, on a canvas large enough to hold every
ray the lens bends into the picture, then resampled into the picture the lens makes. Pixel
conventions as in camera.py.
"""

from dataclasses import dataclass, replace

import cv2
import numpy as np


# undistortPoints' iterations: exact to well under 1e-3 px for k1 = -0.3 at the corners.
UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


@dataclass(frozen=True)
class Lens:
    """OpenCV's distortion coefficients: radial k1, k2, k3 and tangential p1, p2."""

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    @classmethod
    def from_coefficients(cls, values):
        """From OpenCV's order (k1, k2, p1, p2[, k3]); an empty list is the ideal lens."""
        values = [float(v) for v in values]
        if len(values) not in (0, 4, 5):
            raise ValueError(f'lens distortion: expected 0, 4 or 5 coefficients (k1 k2 p1 p2 '
                             f'[k3]), got {len(values)}')
        return cls(*values)

    @property
    def coefficients(self):
        """(5,) in OpenCV's order k1, k2, p1, p2, k3."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])

    @property
    def ideal(self):
        return not self.coefficients.any()


def distorted_pixels(camera, lens, points, z=0.0):
    """(k, 2) pixels where the lens shows (k, 2) arena points at height z (m)."""
    points = np.asarray(points, float).reshape(-1, 2)
    world = np.column_stack([points, np.full(len(points), z)])
    rvec, _ = cv2.Rodrigues(camera.R)
    pixels, _ = cv2.projectPoints(world, rvec, camera.t.astype(float), camera.K,
                                  lens.coefficients)
    return pixels.reshape(-1, 2)


class LensWarp:
    """Turns the ideal frame of `camera` into the frame the lens makes.

    ideal_camera: the same camera on a canvas that holds every ray of the distorted frame
    (its principal point shifted by the canvas' margin); render on it, then apply().
    """

    def __init__(self, camera, lens):
        self.camera = camera
        self.lens = lens
        u, v = np.meshgrid(np.arange(camera.width, dtype=np.float64),
                           np.arange(camera.height, dtype=np.float64))
        pixels = np.column_stack([u.ravel(), v.ravel()]).reshape(-1, 1, 2)
        ideal = cv2.undistortPoints(pixels, camera.K, lens.coefficients, P=camera.K,
                                    criteria=UNDISTORT_CRITERIA).reshape(-1, 2)
        low = np.floor(ideal.min(axis=0)) - 2
        high = np.ceil(ideal.max(axis=0)) + 2
        offset = -np.minimum(low, 0.0)
        size = np.maximum(high + offset, [camera.width, camera.height]).astype(int)
        k = camera.K.copy()
        k[0, 2] += offset[0]
        k[1, 2] += offset[1]
        self.ideal_camera = replace(camera, width=int(size[0]), height=int(size[1]), K=k)
        maps = (ideal + offset).astype(np.float32).reshape(camera.height, camera.width, 2)
        self._map_x = np.ascontiguousarray(maps[..., 0])
        self._map_y = np.ascontiguousarray(maps[..., 1])

    def apply(self, ideal_image, border=0):
        """The distorted frame (camera.height x camera.width) of an ideal_camera frame."""
        return cv2.remap(ideal_image, self._map_x, self._map_y, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=border)

