"""Synthetic overhead-camera frames: floor, corner markers and one marker per robot.

Grey-level (mono8) images as the camera would deliver them, from a PinholeCamera. Markers are
drawn with a one-module white quiet zone, anti-aliased by warping the marker image into its
projected quadrilateral (only its bounding box is touched, so a frame costs little more than
copying the static background).
"""

from dataclasses import dataclass
import math

import cv2
import numpy as np

from curve_formation.vision.lens import Lens, LensWarp
from curve_formation.vision.markers import (
    dictionary,
    marker_bits,
    marker_corners,
    robot_marker_pose,
)


FLOOR = 190        # grey level of the arena floor
SURROUNDINGS = 70  # outside the arena
ROBOT_BODY = 45    # the robot under its marker
IDEAL_LENS = Lens()


@dataclass(frozen=True)
class FloorLine:
    """A line drawn on the arena floor along ordered points (k, 2) (m, arena frame, dense
    enough to look smooth), closed or open, `width` (m) wide, of grey level `grey`.
    """

    points: np.ndarray
    closed: bool
    width: float = 0.012
    grey: int = 40

    def outline(self):
        """The line's edges as polygons (arena frame): one for an open line, the outer and
        inner rings of a closed one (filled even-odd).
        """
        pts = np.asarray(self.points, float)
        if self.closed:
            tangent = np.roll(pts, -1, axis=0) - np.roll(pts, 1, axis=0)
        else:
            tangent = np.gradient(pts, axis=0)
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
        side = 0.5 * self.width * np.column_stack([-tangent[:, 1], tangent[:, 0]])
        left, right = pts + side, pts - side
        return [left, right] if self.closed else [np.vstack([left, right[::-1]])]


@dataclass(frozen=True)
class RenderOptions:
    """Image effects: pixel noise sigma (grey levels), blur sigma (px), brightness factor."""

    noise: float = 0.0
    blur: float = 0.0
    brightness: float = 1.0


class ImageEffects:
    """Applies RenderOptions to a frame: blur, brightness, then pixel noise."""

    def __init__(self, options):
        self.options = options
        self._noise = None

    def __call__(self, image):
        opts = self.options
        if opts.blur > 0:
            image = cv2.GaussianBlur(image, (0, 0), opts.blur)
        if opts.brightness != 1.0:
            image = cv2.convertScaleAbs(image, alpha=opts.brightness)
        if opts.noise > 0:
            if self._noise is None:
                self._noise = np.empty(image.shape, np.int16)
            cv2.randn(self._noise, 0.0, opts.noise)  # type: ignore[call-overload]  # scalars
            image = np.clip(cv2.add(image.astype(np.int16), self._noise), 0, 255).astype(np.uint8)
        return image


class ArenaRenderer:
    """Renders frames of the arena with robots at given poses.

    camera: PinholeCamera; layout: MarkerLayout; arena_size (m); robot_radius (m) of the body
    disc drawn under each marker; lens: the camera's lens.Lens (default ideal): the frame is
    drawn through the pinhole on a larger canvas, then bent as the lens bends it.
    """

    def __init__(self, camera, layout, arena_size, options=RenderOptions(), robot_radius=None,
                 seed=0, lens=IDEAL_LENS):
        self.camera = camera
        self.lens_warp, self._canvas = lens_canvas(camera, lens)
        self.layout = layout
        self.options = options
        self.robot_radius = layout.body_radius(robot_radius or 0.0)
        cv2.setRNGSeed(seed)   # pixel noise comes from OpenCV's generator (fast)
        self._effects = ImageEffects(options)
        self._dictionary = dictionary(layout.dictionary_name)
        self._bits = marker_bits(layout.dictionary_name)
        self._marker_images = {}
        self.arena_size = arena_size
        self.background = self._background()

    def draw_on_floor(self, line=None):
        """Draw a FloorLine on the floor (under the corner markers and robots) from the next
        frame on, replacing the one drawn before; None clears the floor.
        """
        self.background = self._background(line)

    def _background(self, line=None):
        image = np.full((self._canvas.height, self._canvas.width), SURROUNDINGS, np.uint8)
        w, h = self.arena_size
        floor = self._canvas.project([[0, 0], [w, 0], [w, h], [0, h]])
        cv2.fillConvexPoly(image, np.round(floor * 16).astype(np.int32), FLOOR,
                           lineType=cv2.LINE_AA, shift=4)
        if line is not None:
            cv2.fillPoly(image, [np.round(self._canvas.project(edge) * 16).astype(np.int32)
                                 for edge in line.outline()], line.grey,
                         lineType=cv2.LINE_AA, shift=4)
        for marker_id, (x, y) in self.layout.corners.items():
            self._draw_marker(image, marker_id, x, y, 0.0, self.layout.corner_size,
                              self.layout.corner_height)
        return image

    def marker_image(self, marker_id, module_px):
        """Marker `marker_id` with a one-module white quiet zone, module_px per module."""
        key = (marker_id, module_px)
        if key not in self._marker_images:
            inner = cv2.aruco.generateImageMarker(self._dictionary, marker_id,
                                                  (self._bits + 2) * module_px, borderBits=1)
            self._marker_images[key] = cv2.copyMakeBorder(
                inner, module_px, module_px, module_px, module_px, cv2.BORDER_CONSTANT,
                value=255)
        return self._marker_images[key]

    def _draw_marker(self, image, marker_id, x, y, heading, side, z=0.0):
        """Marker `marker_id` centred at (x, y) (m), `side` (m) black square, z (m) up."""
        outer = side * (self._bits + 4) / (self._bits + 2)   # with the quiet zone
        corners = marker_corners(x, y, heading, outer)
        # Source resolution close to the projected one, so the warp neither aliases nor blurs.
        projected = self._canvas.project(corners, z)
        side_px = np.linalg.norm(np.diff(np.vstack([projected, projected[:1]]), axis=0),
                                 axis=1).max()
        module_px = max(1, int(round(side_px / (self._bits + 4))))
        self._warp_into(image, self.marker_image(marker_id, module_px), corners, z)

    def _warp_into(self, image, source, arena_corners, z=0.0):
        """Warp `source` onto the arena quadrilateral (ArUco corner order) at height z (m),
        blending edges.
        """
        n = source.shape[0]
        edge = np.array([[-0.5, -0.5], [n - 0.5, -0.5], [n - 0.5, n - 0.5], [-0.5, n - 0.5]],
                        np.float32)
        target = self._canvas.project(arena_corners, z).astype(np.float32)
        blend_warped(image, source, cv2.getPerspectiveTransform(edge, target))

    def render(self, poses, hidden=(), extra_markers=()):
        """One frame (height x width uint8).

        poses: {agent index (1-based): (x, y, heading)} axle poses (m, rad), arena frame.
        hidden: agents whose marker is covered (their body is still drawn).
        extra_markers: ((marker id, x, y, heading), ...) additional robot-sized markers, e.g.
        a second robot wearing the same id.
        """
        image = self.background.copy()
        for x, y, _ in poses.values():
            body = self._canvas.project(_disc(x, y, self.robot_radius),
                                        self.layout.marker_height)   # the robot's top
            cv2.fillConvexPoly(image, np.round(body * 16).astype(np.int32), ROBOT_BODY,
                               lineType=cv2.LINE_AA, shift=4)
        for agent, (x, y, heading) in poses.items():   # markers on top of every body
            if agent in hidden:
                continue
            mx, my = robot_marker_pose(x, y, heading, self.layout.marker_offset)
            self._draw_marker(image, self.layout.robot_ids[agent - 1], mx, my, heading,
                              self.layout.marker_size, self.layout.marker_height)
        for marker_id, x, y, heading in extra_markers:
            self._draw_marker(image, marker_id, x, y, heading, self.layout.marker_size,
                              self.layout.marker_height)
        if self.lens_warp is not None:
            image = self.lens_warp.apply(image, SURROUNDINGS)
        return self._effects(image)


def lens_canvas(camera, lens):
    """(LensWarp or None, the camera frames are drawn through): the camera itself for an ideal
    lens, else the lens' larger ideal canvas that the warp bends into the camera's frame.
    """
    if lens.ideal:
        return None, camera
    warp = LensWarp(camera, lens)
    return warp, warp.ideal_camera


def blend_warped(image, source, warp):
    """Warp `source` into `image` in place by the 3x3 homography `warp` (source pixel -> image
    pixel), blending its anti-aliased edges; only the bounding box of its footprint is touched.
    """
    h, w = source.shape[:2]
    footprint = cv2.perspectiveTransform(
        np.array([[[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]]],
                 np.float64), np.asarray(warp, np.float64))[0]
    x0, y0 = np.floor(footprint.min(axis=0)).astype(int) - 1
    x1, y1 = np.ceil(footprint.max(axis=0)).astype(int) + 2
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x1, image.shape[1]), min(y1, image.shape[0])
    if x1 <= x0 or y1 <= y0:
        return
    local = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]]) @ warp
    size = (x1 - x0, y1 - y0)
    patch = cv2.warpPerspective(source, local, size, flags=cv2.INTER_LINEAR)
    mask = cv2.warpPerspective(np.ones_like(source, np.float32), local, size,
                               flags=cv2.INTER_LINEAR)
    roi = image[y0:y1, x0:x1]
    roi[:] = np.round(roi * (1 - mask) + patch * mask).astype(np.uint8)


def _disc(x, y, radius, points=32):
    angles = np.linspace(0, 2 * math.pi, points, endpoint=False)
    return np.column_stack([x + radius * np.cos(angles), y + radius * np.sin(angles)])


BOARD_SQUARE_PX = 64   # resolution of the board image the views are warped from
BOARD_BACKGROUND = 120


class BoardRenderer:
    """Frames of a ChArUco board (intrinsics.BoardSpec) held in front of the camera, through
    its lens: what `curve-formation calibrate-camera` is shown.

    camera: PinholeCamera (only K and the image size matter); lens: lens.Lens.
    """

    def __init__(self, camera, spec, lens=IDEAL_LENS, options=RenderOptions(), seed=0):
        self.camera = camera
        self.spec = spec
        self.options = options
        self.lens_warp, self._canvas = lens_canvas(camera, lens)
        cols, rows = spec.squares
        board = spec.board().generateImage((cols * BOARD_SQUARE_PX, rows * BOARD_SQUARE_PX),
                                           marginSize=0, borderBits=1)
        # a white quiet zone of half a square around the board
        self._margin = BOARD_SQUARE_PX // 2
        m = self._margin
        self._board = cv2.copyMakeBorder(board, m, m, m, m, cv2.BORDER_CONSTANT, value=255)
        self._effects = ImageEffects(options)
        cv2.setRNGSeed(seed)

    @property
    def size(self):
        """(width, height) of the board in metres."""
        cols, rows = self.spec.squares
        return cols * self.spec.square_size, rows * self.spec.square_size

    def pose_at(self, pixel, distance, tilt_x_deg=0.0, tilt_y_deg=0.0, spin_deg=0.0):
        """(R, t): the board turned by spin (about its normal), then tilted about its x and y
        axes (degrees), its centre on the ray of ideal `pixel` (u, v) at depth `distance` (m).
        """
        rotation = _rotation(tilt_x_deg, tilt_y_deg, spin_deg)
        ray = np.linalg.solve(self.camera.K, [pixel[0], pixel[1], 1.0])
        centre = np.array([self.size[0] / 2, self.size[1] / 2, 0.0])
        return rotation, distance * ray - rotation @ centre

    def random_poses(self, count, seed=0, distance=(0.5, 0.9), max_tilt_deg=40.0):
        """`count` board poses spread over the frame, each tilted up to max_tilt_deg."""
        rng = np.random.default_rng(seed)
        width, height = self.camera.width, self.camera.height
        poses = []
        for _ in range(count):
            pixel = (rng.uniform(0.1, 0.9) * width, rng.uniform(0.1, 0.9) * height)
            depth = rng.uniform(*distance)
            tilt_x, tilt_y = rng.uniform(-max_tilt_deg, max_tilt_deg, 2)
            poses.append(self.pose_at(pixel, depth, tilt_x, tilt_y, rng.uniform(-30.0, 30.0)))
        return poses

    def render(self, rotation, translation):
        """One frame (height x width uint8) of the board at (R, t), board -> camera (m)."""
        canvas = self._canvas
        image = np.full((canvas.height, canvas.width), BOARD_BACKGROUND, np.uint8)
        ppm = BOARD_SQUARE_PX / self.spec.square_size
        # board image pixel p -> board point (p - margin + 0.5) / ppm (m) -> canvas pixel
        to_board = np.array([[1 / ppm, 0, (0.5 - self._margin) / ppm],
                             [0, 1 / ppm, (0.5 - self._margin) / ppm], [0, 0, 1]])
        rotation = np.asarray(rotation, float)
        plane = np.column_stack([rotation[:, 0], rotation[:, 1], translation])
        warp = canvas.K @ plane @ to_board
        source = self._board
        projected = cv2.perspectiveTransform(
            np.array([[[0, 0], [source.shape[1], 0], [0, source.shape[0]],
                       [source.shape[1], source.shape[0]]]], np.float64), warp)[0]
        shrink = max(np.ptp(projected[:, 0]) / source.shape[1],
                     np.ptp(projected[:, 1]) / source.shape[0])
        if shrink < 0.8:   # downsample first, so that the warp does not alias
            factor = max(shrink * 1.25, 1e-3)
            source = cv2.resize(source, None, fx=factor, fy=factor, interpolation=cv2.INTER_AREA)
            scale = np.diag([1 / factor, 1 / factor, 1.0])
            scale[:2, 2] = 0.5 / factor - 0.5
            warp = warp @ scale
        blend_warped(image, source, warp)
        if self.lens_warp is not None:
            image = self.lens_warp.apply(image, BOARD_BACKGROUND)
        return self._effects(image)


def _rotation(tilt_x_deg, tilt_y_deg, spin_deg):
    ax, ay, az = np.radians([tilt_x_deg, tilt_y_deg, spin_deg])
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    rz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]])
    return rx @ ry @ rz


def camera_view(experiment, resolution=(480, 270), tilt_deg=0.0, distance=2.0):
    """poses (n, 3) -> the overhead camera's frame (grey, uint8) of the arena with the robots
    there, as fake_camera renders it (no noise or blur), for a film's camera view. ValueError
    when the experiment has no camera or arena.
    """
    from curve_formation.vision.camera import overhead_camera
    from curve_formation.vision.markers import MarkerLayout
    spec = experiment.spec
    if spec.camera is None or spec.arena is None:
        raise ValueError(f'{experiment.name}: a camera view needs the `camera` and `arena` '
                         'sections')
    arena = spec.arena.size
    renderer = ArenaRenderer(overhead_camera(arena, tuple(resolution), tilt_deg, distance),
                             MarkerLayout.from_spec(spec.camera), arena,
                             RenderOptions(0.0, 0.0, 1.0), robot_radius=spec.robots.radius)
    return lambda poses: renderer.render({i + 1: tuple(pose) for i, pose in enumerate(poses)})
