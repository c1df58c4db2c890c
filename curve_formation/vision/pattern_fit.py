"""Sub-pixel marker corners: each marker's known pattern aligned to the frame.

cv2.aruco's corners come from lines fitted to the marker's outline in a thresholded image;
on a 4x4 marker 25 px wide they are off by up to half a pixel, the same way frame after frame
(a bias, not noise: measured 0.2 mm RMS, 0.6 mm and 0.3-0.7 degrees at worst on rendered
1280x720 frames). Aligning the marker's whole pattern (every black-white edge inside it, not
only the outline) to the grey image by OpenCV's enhanced correlation coefficient
(`cv2.findTransformECC`, a homography from the pattern to the frame, invariant to the
marker's brightness and contrast) brings that to 0.01-0.07 mm RMS and 0.06-0.12 degrees at worst.
Pixels follow OpenCV (origin at the centre of the top-left pixel).
"""

import collections

import cv2
import numpy as np

from curve_formation.vision.markers import dictionary, marker_bits


MODULE_PX = 4          # pattern pixels per module: about the frame's at 720p over 1.8 m
# The pattern keeps three quarters of the marker's one-module white quiet zone: its outer edge
# is blurred in the frame into whatever surrounds the marker (a robot's body), and matching it
# there shrank the fitted square by 0.13-0.22 px (a whole module kept; 0.01 px with 3/4).
QUIET_PX = 3
ITERATIONS = 50
EPSILON = 1e-4         # stop when the homography's update is this small (pixels)
# A worse alignment is not used (a marker partly covered, smeared): on rendered frames clean
# markers align at 0.94-0.99, a quarter covered at 0.87-0.90, half covered at 0.74-0.85.
MIN_CORRELATION = 0.9
MAX_SHIFT = 0.5        # a corner may move at most this share of a module; else not used


class PatternFit:
    """Refines cv2.aruco's corners of a marker by aligning its pattern to the frame."""

    def __init__(self, dictionary_name):
        self._dictionary = dictionary(dictionary_name)
        self._bits = marker_bits(dictionary_name)
        edge_low, edge_high = QUIET_PX - 0.5, QUIET_PX + (self._bits + 2) * MODULE_PX - 0.5
        # the black square's corners in pattern pixels
        self._square = np.array([[edge_low, edge_low], [edge_high, edge_low],
                                 [edge_high, edge_high], [edge_low, edge_high]], np.float32)
        self._patterns: dict[int, np.ndarray] = {}
        # marker id -> alignments not used, since reset
        self.misses: collections.Counter[int] = collections.Counter()

    def pattern(self, marker_id):
        """Marker `marker_id` in a white margin of QUIET_PX, float32 (0 black, 255 white)."""
        if marker_id not in self._patterns:
            inner = cv2.aruco.generateImageMarker(self._dictionary, marker_id,
                                                  (self._bits + 2) * MODULE_PX, borderBits=1)
            self._patterns[marker_id] = cv2.copyMakeBorder(
                inner, QUIET_PX, QUIET_PX, QUIET_PX, QUIET_PX, cv2.BORDER_CONSTANT,
                value=255).astype(np.float32)
        return self._patterns[marker_id]

    def refine(self, gray, corners, marker_id):
        """(4, 2) corner pixels of marker `marker_id` in `gray`, from cv2.aruco's `corners`
        (cv2.aruco order); `corners` themselves where the alignment fails or is poor.
        """
        corners = np.asarray(corners, np.float64).reshape(4, 2)
        module = np.linalg.norm(corners - np.roll(corners, 1, axis=0), axis=1).max() / (
            self._bits + 2)
        margin = 2.0 * module + 3.0   # the quiet zone (turned by up to 45 degrees) and more
        low = np.maximum(np.floor(corners.min(axis=0) - margin), 0).astype(int)
        high = np.minimum(np.ceil(corners.max(axis=0) + margin),
                          [gray.shape[1], gray.shape[0]]).astype(int)
        window = np.ascontiguousarray(gray[low[1]:high[1], low[0]:high[0]], np.float32)
        warp = cv2.getPerspectiveTransform(self._square,
                                           (corners - low).astype(np.float32))
        try:
            # OpenCV's stubs do not take a None mask with gaussFiltSize; OpenCV does
            correlation, warp = cv2.findTransformECC(  # type: ignore[call-overload]
                self.pattern(marker_id), window, warp.astype(np.float32),
                cv2.MOTION_HOMOGRAPHY,
                (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, ITERATIONS, EPSILON), None, 1)
        except cv2.error:   # did not converge (a covered or smeared marker)
            self.misses[marker_id] += 1
            return corners
        refined = cv2.perspectiveTransform(self._square[None].astype(np.float64),
                                           warp.astype(np.float64))[0] + low
        if (correlation < MIN_CORRELATION or not np.isfinite(refined).all()
                or np.abs(refined - corners).max() > MAX_SHIFT * module):
            self.misses[marker_id] += 1
            return corners
        return refined
