"""Robot poses from overhead-camera frames: ArUco detection and the floor homography.

Pixels follow OpenCV (origin at the centre of the top-left pixel, v down); the arena frame is
metres with y up. The homography maps undistorted pixels to the floor plane; it is estimated
from the corner markers (16 points from 4 markers) and kept when a frame shows too few of
them, so a bumped camera recovers as soon as the corners are seen again.
"""

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import cv2
import numpy as np
import yaml

from curve_formation.vision.camera import apply_homography, raised_plane_homography
from curve_formation.vision.markers import dictionary, pose_from_corners
from curve_formation.vision.pattern_fit import PatternFit


MIN_CORNER_MARKERS = 2        # 8 points: enough for a homography (4 needed), some redundancy
MAX_REPROJECTION_PX = 3.0     # a fit worse than this is refused (a marker misread or moved)
# Continuous calibration fits the homography to the corner markers' pixels averaged over
# frames: each frame moves the average this share of the way (about 10 frames' memory), which
# cuts the frame-to-frame jitter of every pose the homography maps; a corner marker seen more
# than BUMP_PX from its average means the camera moved, and the average starts afresh.
CORNER_SMOOTHING = 0.1
BUMP_PX = 2.0


class CalibrationError(ValueError):
    """A calibration file that cannot be used; the message names the file."""


@dataclass
class Calibration:
    """Pixel -> arena homography and how it was obtained."""

    homography: np.ndarray           # 3x3, undistorted pixels -> arena (m)
    rms_px: float                    # reprojection error of the corner points (pixels)
    corner_ids: tuple = ()

    def save(self, path):
        """Write as YAML (atomically: a crash never leaves half a file)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(path.suffix + '.tmp')
        tmp.write_text(yaml.safe_dump({
            'homography_pixels_to_arena': np.asarray(self.homography).tolist(),
            'rms_reprojection_px': float(self.rms_px),
            'corner_ids': [int(i) for i in self.corner_ids]}, sort_keys=False))
        tmp.replace(path)

    @classmethod
    def load(cls, path):
        path = Path(path)
        try:
            data = yaml.safe_load(path.read_text())
            h = np.array(data['homography_pixels_to_arena'], float)
        except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
            raise CalibrationError(f'{path}: not a calibration file '
                                   f'(homography_pixels_to_arena: 3x3 list): {exc}') from None
        if h.shape != (3, 3) or not np.isfinite(h).all():
            raise CalibrationError(f'{path}: homography_pixels_to_arena: expected a finite '
                                   f'3x3 matrix, got shape {h.shape}')
        return cls(h, float(data.get('rms_reprojection_px', float('nan'))),
                   tuple(data.get('corner_ids', ())))


@dataclass
class Frame:
    """What one image gave.

    poses: {agent: (x, y, heading)} (m, rad, arena frame) of robots seen exactly once.
    duplicates: agents whose marker id was seen more than once (not published).
    pixels: {agent: (4, 2) corner pixels}; unknown_ids: ids that belong to nobody.
    calibrated: whether a homography is available; recalibrated: updated from this frame.
    """

    poses: dict = field(default_factory=dict)
    duplicates: tuple = ()
    pixels: dict = field(default_factory=dict)
    unknown_ids: tuple = ()
    calibrated: bool = False
    recalibrated: bool = False
    corners_seen: int = 0


class MarkerTracker:
    """Detects the layout's markers and turns them into robot poses in the arena frame.

    continuous: re-estimate the homography from every frame with enough corner markers;
    otherwise only `calibration` (e.g. loaded from a file) is used. intrinsics: optional
    (camera_matrix 3x3, distortion) to undistort corner pixels first; needed when the robots'
    markers are not at the corner markers' height (layout heights): they are mapped on their
    own plane, from the camera pose that K and the corners' homography give. refinement:
    'pattern' aligns each marker's pattern to the frame for its corners (pattern_fit, about
    0.6 ms per marker at 720p), 'contour' keeps cv2.aruco's corners.
    """

    def __init__(self, layout, calibration: Optional[Calibration] = None, continuous=True,
                 intrinsics=None, refinement='pattern'):
        self.layout = layout
        self.calibration = calibration
        self.continuous = continuous
        params = cv2.aruco.DetectorParameters()
        # Sub-pixel corners from lines fitted to the marker contour: on rendered 1280x720
        # frames 0.2 degrees heading error against 0.9 with CORNER_REFINE_SUBPIX (measured).
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_CONTOUR
        # Two thresholding passes (windows 3 and 13 px) instead of three, and no candidates
        # with a perimeter under 3 % of the image's larger side (a 4x4 marker that small has
        # under 2 px per module and would not decode): 2x the frame rate at 1080p, with every
        # marker still found (benchmarks/camera_tracker.py).
        params.adaptiveThreshWinSizeMax = 13
        params.minMarkerPerimeterRate = 0.03
        self.detector = cv2.aruco.ArucoDetector(dictionary(layout.dictionary_name), params)
        if refinement not in ('pattern', 'contour'):
            raise ValueError(f"refinement: expected 'pattern' or 'contour', got {refinement!r}")
        self.pattern_fit = PatternFit(layout.dictionary_name) if refinement == 'pattern' else None
        self.agent_of = layout.agent_of
        self.intrinsics: tuple[np.ndarray, np.ndarray] | None = None
        if intrinsics is not None:
            k, dist = intrinsics
            self.intrinsics = (np.asarray(k, float).reshape(3, 3),
                               np.asarray(dist, float).ravel())
        self.raise_by = layout.marker_height - layout.corner_height   # m
        if self.raise_by != 0.0 and self.intrinsics is None:
            raise ValueError(f'markers {self.raise_by:g} m above the corner markers need the '
                             'camera matrix (intrinsics) to be mapped on their plane')
        # (Calibration, its homography for the markers' plane)
        self._raised: tuple[Calibration, np.ndarray] | None = None
        # corner marker id -> its (4, 2) pixels averaged over frames
        self._corner_pixels: dict[int, np.ndarray] = {}

    def detect(self, gray):
        """{marker id: [(4, 2) pixel corners, ...]} of every marker found (undistorted)."""
        corners, ids, _ = self.detector.detectMarkers(gray)
        found: dict[int, list[np.ndarray]] = {}
        if ids is None:
            return found
        for quad, marker_id in zip(corners, ids.ravel(), strict=True):
            pts = quad.reshape(4, 2).astype(float)
            if self.pattern_fit is not None:
                pts = self.pattern_fit.refine(gray, pts, int(marker_id))
            if self.intrinsics is not None:
                pts = self.undistorted(pts)
            found.setdefault(int(marker_id), []).append(pts)
        return found

    def undistorted(self, pixels):
        """(k, 2) pixels as an ideal lens would show them (with the lens calibration)."""
        if self.intrinsics is None:
            raise ValueError('undistorting pixels needs the camera matrix (intrinsics)')
        k, dist = self.intrinsics
        return cv2.undistortPoints(np.asarray(pixels, float).reshape(-1, 1, 2), k, dist,
                                   P=k).reshape(-1, 2)

    def process(self, gray):
        """One frame (uint8 grey image) -> Frame."""
        found = self.detect(gray)
        frame = Frame()
        corner_ids = [i for i in self.layout.corners if len(found.get(i, ())) == 1]
        frame.corners_seen = len(corner_ids)
        if self.continuous and len(corner_ids) >= MIN_CORNER_MARKERS:
            pixels = np.concatenate([self._averaged(i, found[i][0]) for i in corner_ids])
            fitted = fit_homography(pixels, self.layout.corner_points(corner_ids), corner_ids)
            if fitted is not None:
                self.calibration = fitted
                frame.recalibrated = True
        frame.calibrated = self.calibration is not None
        frame.unknown_ids = tuple(sorted(i for i in found if i not in self.agent_of
                                         and i not in self.layout.corners))
        duplicates = []
        for marker_id, quads in found.items():
            agent = self.agent_of.get(marker_id)
            if agent is None:
                continue
            if len(quads) > 1:
                duplicates.append(agent)
                continue
            frame.pixels[agent] = quads[0]
            if frame.calibrated:
                arena = apply_homography(self.marker_homography(), quads[0])
                frame.poses[agent] = pose_from_corners(arena, self.layout.marker_offset)
        frame.duplicates = tuple(sorted(duplicates))
        return frame


    def _averaged(self, marker_id, pixels):
        """Corner marker `marker_id`'s (4, 2) pixels averaged over the frames since the camera
        last moved (CORNER_SMOOTHING, BUMP_PX).
        """
        average = self._corner_pixels.get(marker_id)
        if average is None or np.abs(pixels - average).max() > BUMP_PX:
            average = np.array(pixels, float)
        else:
            average = average + CORNER_SMOOTHING * (pixels - average)
        self._corner_pixels[marker_id] = average
        return average

    def marker_homography(self):
        """Undistorted pixels -> arena (m) on the plane of the robots' markers."""
        calibration = self.calibration
        if calibration is None:
            raise ValueError('not calibrated yet: no corner markers fitted')
        if self.raise_by == 0.0:
            return calibration.homography
        if self._raised is None or self._raised[0] is not calibration:
            assert self.intrinsics is not None   # __init__ refuses raise_by without them
            self._raised = (calibration, raised_plane_homography(
                calibration.homography, self.intrinsics[0], self.raise_by))
        return self._raised[1]


def fit_homography(pixels, arena, corner_ids=()):
    """Least-squares pixel -> arena homography, or None if degenerate or a poor fit."""
    h, _ = cv2.findHomography(np.asarray(pixels, np.float64), np.asarray(arena, np.float64), 0)
    if h is None or not np.isfinite(h).all():
        return None
    back = apply_homography(np.linalg.inv(h), arena)
    rms = float(np.sqrt(np.mean(np.sum((back - pixels) ** 2, axis=1))))
    if rms > MAX_REPROJECTION_PX:
        return None
    return Calibration(h, rms, tuple(corner_ids))
