"""Where a result came from and what its numbers mean: provenance and units of metrics.json.

Every metrics.json (`sim`, `run`, `analyze`, the demo) carries `provenance` (package version,
git commit when the package runs from a checkout, the command line, the experiment file and
its SHA-256, the date in UTC) and `units` (the unit of each key it holds). A run's bag carries
the same provenance in its metadata (analysis.PROVENANCE_KEY).
"""

from datetime import datetime, timezone
import hashlib
import json
from pathlib import Path
import shlex
import subprocess
import sys

from curve_formation import version


# The unit of each key of metrics.json, wherever in the document it appears.
UNITS = {
    'duration': 's', 'start': 's', 'settle_time': 's', 'settle_time_sim': 's',
    'intervals': 's', 'stopped_for': 's', 't': 's', 'time': 's', 'marker_hidden_time': 's',
    'lost_at': 's',
    'curve_size': 'm', 'tolerance': 'm', 'fit_rms_residual': 'm', 'initial_error_norm': 'm',
    'final_error_norm': 'm', 'final_error_norm_sim': 'm', 'final_max_agent_error': 'm',
    'closest_approach': 'm', 'radius': 'm', 'smallest_gap': 'm', 'smallest_gap_sampled': 'm',
    'tracked_vs_true_position_rms': 'm', 'law_pose_vs_true_position_rms': 'm',
    'tracked_vs_true_heading_rms_deg': 'deg',
    'peak_v': 'm/s', 'peak_wheel_speed': 'm/s', 'peak_w': 'rad/s',
    'final_orientation_rates_max': 'rad/s',
    'lyapunov_initial': 'm^2', 'lyapunov_final': 'm^2',
    'final_estimate_error_max': 'as the disturbance over k2 (m/s and rad/s, over 1/s)',
    'latency_ms_p50': 'ms', 'latency_ms_p99': 'ms', 'estimated_latency': 's',
    'cv': '1 (coefficient of variation)', 'min_over_max': '1', 'P': '1', 'Q': '1',
    'count': 'contacts', 'messages': 'messages',
}


def units_of(result):
    """{key: unit} for every key of UNITS that the result (a JSON-ready dict) holds."""
    found = {}

    def walk(value):
        if isinstance(value, dict):
            for key, item in value.items():
                if key in UNITS:
                    found[key] = UNITS[key]
                walk(item)
        elif isinstance(value, list):
            for item in value:
                walk(item)
    walk(result)
    return dict(sorted(found.items()))


def git_commit(folder=None):
    """The commit of the checkout that holds `folder` (default: this package), with '-dirty'
    when it has uncommitted changes; None outside a checkout or without git.
    """
    folder = Path(folder or Path(__file__).resolve().parent)
    try:
        head = subprocess.run(['git', '-C', str(folder), 'rev-parse', 'HEAD'],
                              capture_output=True, text=True, timeout=10)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(['git', '-C', str(folder), 'status', '--porcelain',
                                '--untracked-files=no'], capture_output=True, text=True,
                               timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return head.stdout.strip() + ('-dirty' if dirty else '')


_command: list[str] = []   # the command line, when told (command_line); else sys.argv


def command_line(argv):
    """Tell the command line of this process (the CLI's main, which may be called with its
    own arguments rather than from sys.argv).
    """
    _command[:] = list(argv)


def provenance(experiment_path=None, argv=None):
    """Where a result comes from, as a JSON-ready dict."""
    argv = argv if argv is not None else (_command or sys.argv)
    out = {'package': 'curve_formation', 'version': version(), 'commit': git_commit(),
           'command': shlex.join(argv),
           'date': datetime.now(timezone.utc).isoformat(timespec='seconds')}
    if experiment_path is not None:
        path = Path(experiment_path)
        out['experiment_file'] = str(path.resolve())
        out['experiment_sha256'] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def described(result, experiment_path=None):
    """The result with its `units` and `provenance` (a new dict; the result is kept)."""
    return {**result, 'units': units_of(result),
            'provenance': provenance(experiment_path)}


def provenance_text(experiment_path=None):
    return json.dumps(provenance(experiment_path), sort_keys=True)
