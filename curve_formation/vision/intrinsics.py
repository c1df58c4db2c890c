"""Intrinsic camera calibration from views of a ChArUco board, the way OpenCV users do it.

Each view's board corners are found with cv2.aruco.CharucoDetector and matched to the board's
own 3D points; cv2.calibrateCamera fits K and the distortion coefficients (k1 k2 p1 p2 k3).
A calibration is refused when too few views show the board or the reprojection error (RMS,
pixels) is above a threshold. The result is written as an intrinsics file (YAML) that the
camera tracker reads (`camera.intrinsics_file`).
"""

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml

from curve_formation.vision.markers import dictionary


MIN_CORNERS = 6     # board corners a view must show to count (calibrateCamera needs >= 4)
MIN_VIEWS = 10
MAX_RMS = 1.0       # px: OpenCV's rule of thumb for a usable calibration


class IntrinsicsError(ValueError):
    """A lens calibration that cannot be made or trusted, or an unreadable intrinsics file;
    the message says why.
    """


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: squares (columns, rows), square and marker sides (m), dictionary."""

    squares: tuple[int, int] = (7, 5)
    square_size: float = 0.04
    marker_size: float = 0.03
    dictionary: str = 'DICT_5X5_100'

    def board(self):
        return cv2.aruco.CharucoBoard(tuple(self.squares), self.square_size,
                                      self.marker_size, dictionary(self.dictionary))


@dataclass(frozen=True)
class Intrinsics:
    """K (3x3, px), distortion (k1 k2 p1 p2 k3), the image size (width, height) it holds
    for, the reprojection RMS (px) and how many views it came from.
    """

    camera_matrix: np.ndarray
    distortion: np.ndarray
    image_size: tuple[int, int]
    rms: float
    views: int


def board_points(detector, image):
    """(object points (k, 3) m, image points (k, 2) px) of one view, or None with fewer
    than MIN_CORNERS board corners found.
    """
    corners, ids, _, _ = detector.detectBoard(image)
    if ids is None or len(ids) < MIN_CORNERS:
        return None
    objects, pixels = detector.getBoard().matchImagePoints(corners, ids)
    return objects.reshape(-1, 3), pixels.reshape(-1, 2)


def calibrate(images, spec=BoardSpec(), max_rms=MAX_RMS, min_views=MIN_VIEWS):
    """Intrinsics from grey or colour `images` of the board (all of one size).

    IntrinsicsError with fewer than min_views usable views or an RMS above max_rms.
    """
    detector = cv2.aruco.CharucoDetector(spec.board())
    objects, pixels, size, seen = [], [], None, 0
    for image in images:
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        shape = (image.shape[1], image.shape[0])
        if size is None:
            size = shape
        elif shape != size:
            raise IntrinsicsError(f'images differ in size: {size} and {shape}')
        seen += 1
        found = board_points(detector, image)
        if found is not None:
            objects.append(found[0].astype(np.float32))
            pixels.append(found[1].astype(np.float32))
    if len(objects) < min_views:
        raise IntrinsicsError(f'the board was found in {len(objects)} of {seen} images; at '
                               f'least {min_views} views are needed (tilt the board, cover '
                               'the whole frame)')
    assert size is not None   # min_views >= 1 images were read
    rms, k, dist, _, _ = cv2.calibrateCamera(objects, pixels, size, None, None)
    if not rms <= max_rms:
        raise IntrinsicsError(f'reprojection error {rms:.2f} px is above {max_rms:g} px: '
                               'blurred or moving views, or the board sizes are wrong')
    return Intrinsics(k, dist.ravel(), size, float(rms), len(objects))


def write_intrinsics(path, intrinsics):
    """Write an intrinsics file (YAML), as the camera tracker reads it."""
    data = {'image_size': [int(v) for v in intrinsics.image_size],
            'camera_matrix': [float(v) for v in intrinsics.camera_matrix.ravel()],
            'distortion': [float(v) for v in intrinsics.distortion],
            'reprojection_rms': float(intrinsics.rms), 'views': int(intrinsics.views)}
    Path(path).write_text('# curve-formation calibrate-camera\n'
                          + yaml.safe_dump(data, sort_keys=False))


def read_intrinsics(path, resolution=None):
    """The Intrinsics of a file written by write_intrinsics; IntrinsicsError naming the file
    and the key when it is not one, or (with `resolution` (width, height) px) when it was
    calibrated at another resolution.
    """
    from pydantic import ValidationError

    from curve_formation.core.config import safe_yaml
    from curve_formation.core.config.camera_schema import IntrinsicsFile
    from curve_formation.core.config.errors import validation_problem
    try:
        data = safe_yaml.load(Path(path).read_bytes())
    except (OSError, safe_yaml.InputError) as exc:
        raise IntrinsicsError(f'{path}: {exc}') from None
    if not isinstance(data, dict):
        raise IntrinsicsError(f'{path}: expected a mapping with camera_matrix, distortion '
                               'and image_size (curve-formation calibrate-camera writes it)')
    try:
        spec = IntrinsicsFile.model_validate(data)
    except ValidationError as exc:
        key, message = validation_problem(exc)
        raise IntrinsicsError(f'{path}: {key}: {message}') from None
    size = (int(spec.image_size[0]), int(spec.image_size[1]))
    if resolution is not None and size != tuple(resolution):
        raise IntrinsicsError(f'{path} was calibrated at {size[0]}x{size[1]}, the camera '
                              f'delivers {resolution[0]}x{resolution[1]} (camera.resolution)')
    rms = np.nan if spec.reprojection_rms is None else spec.reprojection_rms
    return Intrinsics(np.array(spec.camera_matrix, float).reshape(3, 3),
                      np.array(spec.distortion, float), size, float(rms), spec.views)


def read_images(source, every=1, limit=None):
    """Frames from a folder of images (sorted by name), a video file or a device number:
    every `every`-th frame, `limit` frames at most (a device streams until stopped).
    """
    frames = _frames(source)
    for index, frame in enumerate(frames):
        if limit is not None and index // every >= limit:
            frames.close()
            return
        if index % every == 0:
            yield frame


def _frames(source):
    folder = Path(str(source))
    if folder.is_dir():
        for path in sorted(folder.iterdir()):
            image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if image is not None:
                yield image
        return
    capture = cv2.VideoCapture(int(source) if str(source).isdigit() else str(source))
    if not capture.isOpened():
        raise IntrinsicsError(f'{source}: neither a folder of images nor a video or device')
    try:
        while True:
            ok, frame = capture.read()
            if not ok:
                return
            yield frame
    finally:
        capture.release()
