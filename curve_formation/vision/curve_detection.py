"""A curve drawn on the arena floor (tape, rope, a marker line), found in overhead-camera frames.

Pipeline, per frame: pixels darker than their neighbourhood by `contrast` grey levels
(cv2.adaptiveThreshold: uneven lighting does not matter), outside a mask of what lies beyond
the arena, under a robot's body or on a corner marker (drawn in the frame), are mapped to the
floor (arena frame, m) through the floor homography. They are binned into cells two line
widths wide; the cells are
chained by a minimum spanning tree whose edges may bridge gaps up to `max_gap` (a robot parked
on the line hides a piece of it), and the tree's longest path orders them. The chain is closed
when its two ends are within `max_gap` of each other. Each ordered point is then moved to the
middle of the line pixels beside it (across the local tangent), which takes the centreline to
well under a pixel.
"""

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.sparse.csgraph import connected_components, dijkstra, minimum_spanning_tree
from scipy.spatial import cKDTree

from curve_formation.core.formation.curve_sources import polyline_distances, polyline_rms_distance
from curve_formation.vision.camera import apply_homography, raised_plane_homography


CELL_WIDTHS = 2   # cells are two line widths wide: one cell per stretch of line, little zig-zag
LINK_CELLS = 3    # chain neighbours further apart than this many cells are across a gap


@dataclass(frozen=True)
class DetectionOptions:
    """width (m) of the drawn line; contrast (grey levels) it is darker than the floor around
    it; clearance (m) masked around each robot's body beyond its radius; max_gap (m): the
    longest stretch of hidden line that is bridged (None: a robot's masked disc and two line
    widths, see CurveDetector.max_gap); min_length (m) of a chain reported as a curve.
    """

    width: float = 0.012
    contrast: float = 30.0
    clearance: float = 0.015
    max_gap: float | None = None
    min_length: float = 0.2


@dataclass(frozen=True)
class DetectedCurve:
    """Ordered centreline points (k, 2) (m, arena frame), whether the curve is closed, and how
    many line pixels it was found from.
    """

    points: np.ndarray
    closed: bool
    pixels: int

    def distance_to(self, other):
        """RMS distance (m) from this curve's points to `other`'s polyline (closed as it is)."""
        return polyline_rms_distance(self.points, other.points, other.closed)

    @property
    def length(self):
        """Length (m) of the polyline through the points (closed: round)."""
        pts = np.vstack([self.points, self.points[:1]]) if self.closed else self.points
        return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())


class CurveDetector:
    """Finds the drawn curve in grey frames of a camera whose floor homography is known.

    arena_size (m); robot_radius (m) of the bodies masked out; keep_out: ((x, y, radius), ...)
    floor discs (m) never read as line, e.g. the corner markers; pixels_per_metre of the frame
    on the floor, roughly (sets the neighbourhood of the threshold).
    """

    def __init__(self, arena_size, robot_radius, keep_out=(), options=DetectionOptions(),
                 pixels_per_metre=700.0):
        self.arena_size = tuple(float(v) for v in arena_size)
        self.robot_radius = float(robot_radius)
        self.keep_out = np.asarray(keep_out, float).reshape(-1, 3)
        self.options = options
        self.max_gap = options.max_gap
        if self.max_gap is None:   # a body's masked disc, and the cells either side of it
            self.max_gap = 2 * (self.robot_radius + options.clearance) + 4 * options.width
        block = int(round(4 * options.width * pixels_per_metre)) | 1   # odd, about 4 widths
        self.block = max(block, 7)

    def line_pixels(self, gray, mask=None):
        """(k, 2) pixel coordinates (u, v) of pixels darker than their surroundings; with
        `mask` (an image the frame's size), only those where it is not zero.
        """
        binary = cv2.adaptiveThreshold(gray, 255, cv2.ADAPTIVE_THRESH_MEAN_C,
                                       cv2.THRESH_BINARY_INV, self.block, self.options.contrast)
        if mask is not None:
            binary &= mask
        found = cv2.findNonZero(binary)
        return np.empty((0, 2)) if found is None else found.reshape(-1, 2).astype(np.float64)

    def detect(self, gray, floor_from_pixels, bodies=(), undistort=None, distort=None):
        """The curve in one frame, or None when no chain of at least min_length is seen.

        floor_from_pixels: 3x3 homography, undistorted pixels -> floor (m); bodies: (k, 2)
        where each robot's body appears on the floor (m); undistort, distort: with a lens,
        functions of (k, 2) pixels -> undistorted pixels and back.
        """
        mask = self.readable_mask(gray.shape, floor_from_pixels,
                                  np.asarray(bodies, float).reshape(-1, 2), distort)
        pixels = self.line_pixels(gray, mask)
        if undistort is not None and len(pixels):
            pixels = undistort(pixels)
        points = apply_homography(floor_from_pixels, pixels)
        w, h = self.arena_size
        points = points[(points[:, 0] > 0) & (points[:, 0] < w) & (points[:, 1] > 0)
                        & (points[:, 1] < h)]
        if len(points) == 0:
            return None
        chain, closed = self._ordered_cells(points)
        if chain is None:
            return None
        centre = _centred(chain, points, closed, self.options.width,
                          link=LINK_CELLS * CELL_WIDTHS * self.options.width)
        return DetectedCurve(centre, closed, len(points))

    def readable_mask(self, shape, floor_from_pixels, bodies, distort=None):
        """uint8 image of where the line is searched: the arena shrunk by half a line width,
        without the robots' bodies (robot_radius + clearance) and the keep-out discs: the
        floor's edge against its surroundings and the bodies are dark too.
        """
        to_pixels = np.linalg.inv(floor_from_pixels)

        def outline(points):
            pixels = apply_homography(to_pixels, points)
            return np.round(pixels if distort is None else distort(pixels)).astype(np.int32)
        w, h = self.arena_size
        m = 0.5 * self.options.width
        corners = np.array([[m, m], [w - m, m], [w - m, h - m], [m, h - m]])
        side = np.linspace(0.0, 1.0, 30, endpoint=False)[:, None]
        edge = np.vstack([a + side * (b - a)
                          for a, b in zip(corners, np.roll(corners, -1, 0), strict=True)])
        mask = np.zeros(shape[:2], np.uint8)
        cv2.fillPoly(mask, [outline(edge)], 255)
        body = self.robot_radius + self.options.clearance
        discs = np.vstack([np.column_stack([bodies, np.full(len(bodies), body)]),
                           self.keep_out])
        angles = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
        ring = np.column_stack([np.cos(angles), np.sin(angles)])
        # a polygon just outside the circle: its sides stay beyond the radius
        grow = 1.0 / np.cos(np.pi / len(angles))
        for x, y, r in discs:   # one by one: fillPoly would leave overlaps unfilled
            cv2.fillConvexPoly(mask, outline((x, y) + grow * r * ring), 0)
        return mask

    def _ordered_cells(self, points):
        """(ordered cell centroids (k, 2), closed) of the longest chain, or (None, False)."""
        opts = self.options
        cell = CELL_WIDTHS * opts.width
        keys = np.floor(points / cell).astype(np.int64)
        keys = (keys[:, 0] << 32) + keys[:, 1]   # one integer per cell: a 1-D unique
        _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
        centroids = np.column_stack([np.bincount(inverse, points[:, k]) / counts
                                     for k in range(2)])
        # a cell must hold a fair share of a line crossing it (drops isolated specks)
        full = counts >= 0.1 * counts.max()
        centroids = centroids[full]
        if len(centroids) < 3:
            return None, False
        graph = cKDTree(centroids).sparse_distance_matrix(
            cKDTree(centroids), self.max_gap, output_type='coo_matrix').tocsr()
        tree = minimum_spanning_tree(graph)
        _, labels = connected_components(tree, directed=False)
        biggest = np.argmax(np.bincount(labels))
        start = np.flatnonzero(labels == biggest)[0]
        far = dijkstra(tree, directed=False, indices=start)
        a = int(np.nanargmax(np.where(np.isfinite(far), far, np.nan)))
        dist, previous = dijkstra(tree, directed=False, indices=a, return_predecessors=True)
        b = int(np.nanargmax(np.where(np.isfinite(dist), dist, np.nan)))
        if dist[b] < opts.min_length:
            return None, False
        path = [b]
        while path[-1] != a:
            path.append(int(previous[path[-1]]))
        chain = centroids[path[::-1]]
        closed = bool(np.linalg.norm(chain[0] - chain[-1]) <= self.max_gap
                      and dist[b] > 4 * self.max_gap)
        return chain, closed


def finder_for(tracker, camera, arena_size, robot_radius=0.0):
    """DrawnCurveFinder for an experiment's `camera` section (its `drawn_curve` options),
    `arena.size` (m) and `robots.radius` (m; 0 = the renderer's default body).
    """
    spec = camera.drawn_curve
    options = DetectionOptions(spec.width, spec.contrast, spec.clearance, spec.max_gap)
    layout = tracker.layout
    keep_out = [(x, y, layout.corner_reach() + spec.width) for x, y in layout.corners.values()]
    detector = CurveDetector(arena_size, layout.body_radius(robot_radius), keep_out, options,
                             pixels_per_metre=camera.resolution[0] / arena_size[0])
    return DrawnCurveFinder(tracker, detector)


class DrawnCurveFinder:
    """The drawn curve in the frames a MarkerTracker reads: its lens, its floor homography
    (the corner markers' plane taken down to the floor), and the robots' bodies where the
    camera shows them (a body's top seen from an angle lies beside the axle on the floor).
    """

    def __init__(self, tracker, detector):
        self.tracker, self.detector = tracker, detector

    def find(self, gray, robot_positions):
        """DetectedCurve or None; robot_positions (k, 2) (m, arena frame) of the robots."""
        tracker = self.tracker
        if tracker.calibration is None:
            return None
        layout = tracker.layout
        floor = tracker.calibration.homography
        if layout.corner_height:
            floor = raised_plane_homography(floor, tracker.intrinsics[0], -layout.corner_height)
        bodies = np.asarray(robot_positions, float).reshape(-1, 2)
        if layout.marker_height != 0.0 and len(bodies):
            pixels = apply_homography(np.linalg.inv(tracker.marker_homography()), bodies)
            bodies = apply_homography(floor, pixels)
        undistort = distort = None
        if tracker.intrinsics is not None:
            k, dist = tracker.intrinsics
            undistort = tracker.undistorted

            def distort(pixels):
                rays = np.column_stack([pixels, np.ones(len(pixels))]) @ np.linalg.inv(k).T
                out, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), k, dist)
                return out.reshape(-1, 2)
        return self.detector.detect(gray, floor, bodies, undistort, distort)


class CurveWatch:
    """Decides which detections are published, so that pixel noise and robots never switch
    the curve.

    What a frame shows is compared with the published curve one way: a detection whose
    points lie on the published line (RMS within `change`, m) is the same curve, however
    much of it robots hide (parked on a line, nine robots can cover most of it). It is
    published when it leaves the published line in `confirm` detections in a row (a hand or a
    robot passing over the line does not count), or when the same line is seen `longer` (m)
    longer than when it was published (robots have moved off an end).
    """

    def __init__(self, change=0.003, confirm=2, longer=0.03, width=0.012):
        self.change, self.confirm, self.longer = change, confirm, longer
        self.link = LINK_CELLS * CELL_WIDTHS * width   # neighbours further apart: a gap
        self.published = None
        self._candidate, self._seen = None, 0

    def offer(self, detected):
        """The curve to publish now (the detection), or None."""
        if detected is None:
            self._candidate, self._seen = None, 0
            return None
        if self.published is not None and not self._moved(detected, self.published):
            self._candidate, self._seen = None, 0
            if detected.length > self.published.length + self.longer:
                self.published = detected
                return detected
            return None
        if self._candidate is not None and not self._moved(detected, self._candidate):
            self._seen += 1
        else:
            self._seen = 1
        self._candidate = detected
        if self._seen < self.confirm:
            return None
        self.published, self._candidate, self._seen = detected, None, 0
        return detected

    def _moved(self, seen, reference):
        """Whether `seen` leaves the line of `reference` (or has closed): RMS distance of its
        points to that line, leaving out those where the reference saw no line: beyond an
        open line's ends, or across a stretch a robot hid (a chord there is not the line).
        """
        if seen.closed and not reference.closed:
            return True
        distance, where = polyline_distances(seen.points, reference.points, reference.closed)
        ring = (np.vstack([reference.points, reference.points[:1]]) if reference.closed
                else reference.points)
        hops = np.linalg.norm(np.diff(ring, axis=0), axis=1)
        segment = np.minimum(where.astype(int), len(hops) - 1)
        known = hops[segment] <= self.link
        if not reference.closed:
            known &= (where > 0.0) & (where < len(hops))
        inside = distance[known]
        return len(inside) == 0 or float(np.sqrt(np.mean(inside ** 2))) > self.change


def _centred(chain, points, closed, width, link, passes=2):
    """Chain points moved across the local tangent to the mean of the line points nearest to
    them (each line point belongs to its nearest chain point: a slab across the line, so the
    mean lies on the centreline). Neighbours further apart than `link` (m) are across a gap:
    neither smoothed nor read for the tangent over it.
    """
    centre = chain.copy()
    for step in range(passes + 1):
        ahead = np.roll(centre, -1, axis=0)
        behind = np.roll(centre, 1, axis=0)
        has_ahead = np.linalg.norm(ahead - centre, axis=1) <= link
        has_behind = np.linalg.norm(behind - centre, axis=1) <= link
        if not closed:
            has_ahead[-1] = has_behind[0] = False
        ahead = np.where(has_ahead[:, None], ahead, centre)
        behind = np.where(has_behind[:, None], behind, centre)
        if step == 0:
            # (1, 2, 1) / 4 within runs: takes out a zig-zag between cells beside each other
            inner = has_ahead & has_behind
            centre[inner] = 0.25 * (ahead + 2 * centre + behind)[inner]
            continue
        tangent = ahead - behind
        tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
        normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
        distance, nearest = cKDTree(centre).query(points)
        across = np.einsum('ij,ij->i', points - centre[nearest], normal[nearest])
        use = (distance < width) & (np.abs(across) < width)
        count = np.bincount(nearest[use], minlength=len(centre))
        shift = np.bincount(nearest[use], across[use], minlength=len(centre))
        moved = count > 0
        centre[moved] += normal[moved] * (shift[moved] / count[moved])[:, None]
    # consecutive duplicates would break a chord-length parameterisation
    keep = np.concatenate([[True], np.linalg.norm(np.diff(centre, axis=0), axis=1) > 1e-9])
    return centre[keep]
