"""The files an experiment's `camera` section names, read and checked as the tracker reads them,
so that `curve-formation check` refuses what the tracker would refuse at start.
"""

from curve_formation.core.config.errors import ConfigError
from curve_formation.core.config.experiment import beside_experiment
from curve_formation.vision.intrinsics import IntrinsicsError, read_intrinsics
from curve_formation.vision.tracker import Calibration, CalibrationError


def check_camera_files(experiment):
    """One line per file checked; ConfigError naming the experiment, the key and the problem
    for a lens calibration that is unreadable or of another resolution, an unreadable saved
    homography, or calibration 'fixed' without one.
    """
    camera = experiment.spec.camera
    if camera is None:
        return []
    checked = []
    path = beside_experiment(experiment, camera.intrinsics_file)
    if path is not None:
        try:
            lens = read_intrinsics(path, camera.resolution)
        except IntrinsicsError as exc:
            raise ConfigError(experiment.source, 'camera.intrinsics_file', str(exc)) from None
        checked.append(f'lens calibration {path}: {lens.image_size[0]}x{lens.image_size[1]}, '
                       f'reprojection {lens.rms:.2f} px from {lens.views} views')
    path = beside_experiment(experiment, camera.calibration_file)
    if path is not None and path.exists():
        try:
            calibration = Calibration.load(path)
        except CalibrationError as exc:
            raise ConfigError(experiment.source, 'camera.calibration_file', str(exc)) from None
        checked.append(f'saved homography {path}: corner reprojection '
                       f'{calibration.rms_px:.2f} px')
    elif camera.calibration == 'fixed':
        where = 'none is given' if path is None else f'{path} does not exist'
        raise ConfigError(experiment.source, 'camera.calibration_file', "calibration 'fixed' "
                          f'needs a saved homography; {where}')
    return checked
