"""The camera section of an experiment file (pydantic): markers, arena calibration, lens,
the drawn curve and the fake camera's rendering. Units: m, pixels, Hz.
"""

from typing import Literal, Optional

from pydantic import Field, field_validator, model_validator

from curve_formation.core.config.strict import Pair, Strict


class CornerMarker(Strict):
    id: int = Field(ge=0, description='ArUco id of a fixed marker on the arena floor')
    position: Pair = Field(description='its centre in the arena frame (m); its x axis along '
                           "the arena's x axis")


class FakeCameraSpec(Strict):
    """How fake_camera renders the arena (tests and demos only)."""

    tilt_deg: float = Field(0.0, ge=0, lt=60, description='camera tilt from straight down')
    height: float = Field(2.0, gt=0, description='camera distance from the arena centre (m)')
    noise: float = Field(0.0, ge=0, description='pixel noise standard deviation (grey levels)')
    blur: float = Field(0.0, ge=0, description='Gaussian blur sigma (pixels)')
    brightness: float = Field(1.0, gt=0, description='brightness factor')
    distortion: list[float] = Field(default_factory=list, description='lens the fake camera '
                                    'renders: OpenCV distortion coefficients k1 k2 p1 p2 '
                                    '[k3]; [] = an ideal lens')

    @field_validator('distortion')
    @classmethod
    def _distortion_size(cls, value: list[float]) -> list[float]:
        return distortion_count(value, (0, 4, 5), 'k1 k2 p1 p2 [k3]')


OPENCV_DISTORTION_COUNTS = (0, 4, 5, 8, 12, 14)


def distortion_count(value: list[float], counts: tuple[int, ...], names: str) -> list[float]:
    """`value` if it has one of `counts` coefficients (OpenCV's distortion vector lengths)."""
    if len(value) not in counts:
        expected = ', '.join(map(str, counts[:-1])) + f' or {counts[-1]}'
        raise ValueError(f'expected {expected} coefficients ({names}), got {len(value)}')
    return value


class Intrinsics(Strict):
    camera_matrix: list[float] = Field(min_length=9, max_length=9,
                                       description='3x3 camera matrix K, row by row (pixels)')
    distortion: list[float] = Field(default_factory=list,
                                    description='OpenCV distortion coefficients k1 k2 p1 p2 ..')

    @field_validator('distortion')
    @classmethod
    def _distortion_size(cls, value: list[float]) -> list[float]:
        return distortion_count(value, OPENCV_DISTORTION_COUNTS, 'k1 k2 p1 p2 [k3 ..]')


class IntrinsicsFile(Intrinsics):
    """A lens calibration file as `curve-formation calibrate-camera` writes it."""

    image_size: tuple[int, int] = Field(description='width, height (pixels) the calibration '
                                        'holds for')
    reprojection_rms: Optional[float] = Field(None, ge=0, description='calibration RMS (px)')
    views: int = Field(0, ge=0, description='board views the calibration came from')

    @field_validator('image_size')
    @classmethod
    def _positive_size(cls, value: tuple[int, int]) -> tuple[int, int]:
        if min(value) <= 0:
            raise ValueError('width and height must be > 0')
        return value


class DrawnCurveSpec(Strict):
    """A curve drawn on the arena floor that the camera tracker finds and the robots follow
    (vision/curve_detection.py). The fake camera draws the experiment's `curves` as this line.
    """

    width: float = Field(0.012, gt=0, description='width of the drawn line (m)')
    contrast: float = Field(30.0, gt=0, le=255, description='how much darker the line is than '
                            'the floor around it (grey levels)')
    clearance: float = Field(0.015, ge=0, description="floor masked around each robot's body "
                             'beyond robots.radius (m)')
    max_gap: Optional[float] = Field(None, gt=0, description='longest stretch of line hidden '
                                     'by a robot that is bridged (m); default: a masked body '
                                     'and four line widths')
    rate_hz: float = Field(2.0, gt=0, description='how often frames are searched for the curve')
    change: float = Field(0.003, gt=0, description='a curve is published again only when it '
                          'moved by more than this, RMS (m)')
    grey: int = Field(40, ge=0, le=255, description='grey level of the line the fake camera '
                      'draws')


class CameraSpec(Strict):
    """The overhead camera: markers, arena calibration, fake camera options."""

    dictionary: str = Field('DICT_4X4_50', description='cv2.aruco predefined dictionary name')
    robot_ids: list[int] = Field([], description='marker id on agent 1, 2, .., n (left out: '
                                 "robots.fleet's markers)")
    marker_size: float = Field(gt=0, description="side of a robot marker's black square (m)")
    marker_offset: Pair = Field((0.0, 0.0), description='marker centre relative to the axle '
                                'centre in the robot frame, x forward (m)')
    corners: list[CornerMarker] = Field(min_length=2, description='fixed floor markers with '
                                        'known arena positions (at least 2; 4 recommended)')
    corner_size: float = Field(gt=0, description="side of a corner marker's black square (m)")
    marker_height: float = Field(0.0, ge=0, description="height of the robots' markers above "
                                 'the floor (m); the tracker maps them on that plane')
    corner_height: float = Field(0.0, ge=0, description='height of the corner markers above '
                                 'the floor (m), e.g. on stands at marker height')
    calibration: Literal['continuous', 'fixed'] = Field(
        'continuous', description='continuous: homography re-estimated from the corner markers '
        'in every frame that shows enough of them; fixed: read from calibration_file only')
    calibration_file: Optional[str] = Field(None, description='saved homography (YAML), '
                                            'reloaded at start; relative to the experiment file')
    intrinsics: Optional[Intrinsics] = None
    intrinsics_file: Optional[str] = Field(
        None, description='lens calibration (YAML) written by `curve-formation '
        'calibrate-camera`; relative to the experiment file; instead of `intrinsics`')
    corner_refinement: Literal['pattern', 'contour'] = Field(
        'pattern', description="pattern: each marker's corners from its whole pattern aligned "
        "to the frame (sub-pixel, unbiased); contour: cv2.aruco's corners (faster, biased by "
        'up to half a pixel)')
    resolution: tuple[int, int] = Field((1280, 720), description='width, height (pixels)')
    rate_hz: float = Field(30.0, gt=0, description='frame rate of the (fake) camera')
    lost_timeout: float = Field(0.5, gt=0, description='a robot unseen for this long is '
                                'reported lost (s)')
    fake: FakeCameraSpec = FakeCameraSpec()
    drawn_curve: Optional[DrawnCurveSpec] = Field(
        None, description='the curve is drawn on the floor: the tracker finds it and the curve '
        'server publishes what it finds instead of the `curves` schedule')

    @model_validator(mode='after')
    def _one_lens_calibration(self) -> 'CameraSpec':
        if self.intrinsics is not None and self.intrinsics_file is not None:
            raise ValueError('give `intrinsics` or `intrinsics_file`, not both')
        return self

    @model_validator(mode='after')
    def _distinct_ids(self) -> 'CameraSpec':
        ids = list(self.robot_ids) + [c.id for c in self.corners]
        repeated = sorted({i for i in ids if ids.count(i) > 1})
        if repeated:
            raise ValueError(f'marker ids must be distinct across robots and corners, '
                             f'repeated: {repeated}')
        return self
