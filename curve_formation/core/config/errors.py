"""ConfigError, the one error of a file that cannot be used, and how a schema violation is
said in it (file: key: what was expected).
"""

from collections.abc import Sequence

from pydantic import ValidationError

from curve_formation.core.config import safe_yaml


class ConfigError(ValueError):
    """An experiment file that cannot be used; the message names file, key and expectation."""

    def __init__(self, source: object, key: str, message: str) -> None:
        self.source, self.key = str(source), key
        super().__init__(f'{source}: {key}: {message}' if key else f'{source}: {message}')


def _format_location(loc: Sequence[int | str]) -> str:
    parts = []
    for item in loc:
        if isinstance(item, int):
            parts.append(f'[{item}]')
        else:
            parts.append(('.' if parts else '') + str(item))
    return ''.join(parts) or '(top level)'


def validation_problem(exc: ValidationError) -> tuple[str, str]:
    """(key path, what was wrong and what was given) of a pydantic error's first problem."""
    err = exc.errors()[0]
    more = f' (and {exc.error_count() - 1} more problems)' if exc.error_count() > 1 else ''
    got = (f' (got {safe_yaml.shorten(repr(err["input"]), 80)})'
           if err['type'] != 'missing' and not isinstance(err['input'], dict) else '')
    return _format_location(err['loc']), err['msg'] + got + more
