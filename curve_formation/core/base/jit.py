"""numba compilation of core functions, shared by the batch simulator and the controllers'
compiled law (AgentConfig.compiled), and the guard that keeps numba's cache current.
"""

from collections.abc import Callable, Iterator
from contextlib import contextmanager
import fcntl
import hashlib
from pathlib import Path
import types
from typing import Any, cast

import numba


# The sources numba compiles in, relative to core/ (a cached function is checked against its
# own file only, not against the functions compiled into it from these).
SOURCES = ('controller/step.py', 'controller/law.py', 'controller/limits.py',
           'controller/observer.py', 'controller/driving.py', 'controller/safety.py',
           'controller/command_log.py', 'controller/motion_observer.py', 'controller/others.py',
           'controller/inputs.py',
           'formation/dynamics.py', 'world/bodies.py', 'world/kinematic.py', 'sim/kernel.py')
CORE = Path(__file__).resolve().parent.parent


def cache_folder(folder: Path) -> Path:
    """Where numba caches what it compiles from the sources in `folder`: __pycache__ beside
    them, or under NUMBA_CACHE_DIR when that is set (as scripts/bootstrap.sh does), in the
    subfolder numba itself derives from the sources' folder.
    """
    from numba.core import caching, config
    if config.CACHE_DIR:
        return Path(config.CACHE_DIR) / caching._CacheLocator.get_suitable_cache_subpath(
            str(folder / 'any.py'))
    return folder / '__pycache__'


def drop_stale_cache(core: Path = CORE) -> bool:
    """Delete numba's compiled caches when a source it compiles in (SOURCES) changed.

    numba checks a cached function against its own source file only, not against the
    functions it compiled in from other modules: after an edit of law.py the stepping loop
    would run the old law. Installed copies never change; an unwritable cache is left alone.
    """
    sources = b''.join((core / name).read_bytes() for name in SOURCES)
    digest = hashlib.sha256(sources).hexdigest()
    stamp = cache_folder(core) / 'compiled.sources.sha256'
    try:
        if stamp.read_text() == digest:
            return False
    except OSError:
        pass
    try:
        for folder in sorted({(core / name).parent for name in SOURCES}):
            for path in cache_folder(folder).glob('*.nb[ic]'):
                path.unlink()
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.write_text(digest)
    except OSError:
        return False
    return True


drop_stale_cache()

_COMPILED: dict[types.FunctionType, Callable[..., Any]] = {}


def compiled(function: Callable[..., Any]) -> Callable[..., Any]:
    """numba-compile a core function, after the core functions it calls (compiled in)."""
    source = cast(types.FunctionType, function)   # a plain Python function of the core
    if source in _COMPILED:
        return _COMPILED[source]
    callees: dict[str, Callable[..., Any]] = {}
    for name in source.__code__.co_names:
        value = source.__globals__.get(name)
        if (isinstance(value, types.FunctionType)
                and value.__module__.startswith('curve_formation.core.')):
            callees[name] = compiled(value)
    scope = dict(source.__globals__, **callees)
    copy = types.FunctionType(source.__code__, scope, source.__name__, source.__defaults__)
    _COMPILED[source] = numba.njit(cache=True)(copy)
    return _COMPILED[source]


@contextmanager
def one_compiler_at_a_time(function: Callable[..., Any]) -> Iterator[None]:
    """Compile `function` (a core function, see `compiled`) in this block one process at a
    time: several controller processes starting on a cold cache (a fresh install) would each
    compile the same functions at once, minutes on two cores; this way the first compiles and
    writes the cache and the others load it. Once the cache holds the function, processes
    load it side by side without the lock. Without a writable cache, no lock.
    """
    code = cast(types.FunctionType, function).__code__
    folder = cache_folder(Path(code.co_filename).parent)
    if any(folder.glob(f'*.{code.co_name}-*.nbi')):
        yield
        return
    try:
        folder.mkdir(parents=True, exist_ok=True)
        handle = open(folder / 'compile.lock', 'a')
    except OSError:
        yield
        return
    with handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)
