"""Reading experiment files safely: whatever the bytes, a mapping or one clear error.

An experiment file must be UTF-8 text of at most MAX_BYTES, nested at most MAX_DEPTH deep,
without YAML aliases (an alias can expand exponentially: "billion laughs") and without a key
given twice in one mapping (a pasted block would silently override a setting). The event
stream is scanned first, iteratively, so a deeply nested file cannot exhaust the recursion
limit of PyYAML's composer; only then is it composed, with a duplicate-key check.
"""

from typing import Any

import yaml


MAX_BYTES = 1_000_000
MAX_DEPTH = 40
MAX_EVENTS = 2_000_000


class InputError(ValueError):
    """A file that cannot be read as an experiment; the message says why (no file name)."""


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key that appears twice in one mapping."""

    def construct_mapping(self, node: Any, deep: bool = False) -> dict[Any, Any]:
        seen: dict[object, int] = {}   # key -> its line (0-based)
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            try:
                repeated = key in seen
            except TypeError:   # an unhashable key: the base class says so
                break
            if repeated:
                raise InputError(f'key {shorten(key)!r} appears twice in one mapping (lines '
                                 f'{seen[key] + 1} and {key_node.start_mark.line + 1})')
            seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep=deep)


def load(data: str | bytes) -> Any:
    """The Python value of YAML `data` (bytes or str); InputError if it is not acceptable."""
    if isinstance(data, bytes):
        if len(data) > MAX_BYTES:
            raise InputError(f'the file holds more than {MAX_BYTES} bytes; at most that '
                             'expected')
        try:
            text = data.decode('utf-8-sig')
        except UnicodeDecodeError as exc:
            kind = 'UTF-16' if data[:2] in (b'\xff\xfe', b'\xfe\xff') else 'binary or another'
            raise InputError(f'not UTF-8 text ({kind} encoding: byte {exc.start} is '
                             f'{data[exc.start]:#04x}); save the file as UTF-8') from None
    else:
        text = data
    if '\x00' in text:
        raise InputError('not a text file (it holds NUL characters)')
    _scan(text)
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)   # noqa: S506 - a SafeLoader
    except yaml.YAMLError as exc:
        raise InputError(f'not valid YAML: {shorten(str(exc), 300)}') from None


def _scan(text: str | bytes) -> None:
    """Refuse aliases, nesting deeper than MAX_DEPTH and more than MAX_EVENTS events."""
    depth = events = 0
    try:
        for event in yaml.parse(text, Loader=yaml.SafeLoader):
            events += 1
            if events > MAX_EVENTS:
                raise InputError(f'the file holds more than {MAX_EVENTS} YAML values')
            if isinstance(event, yaml.AliasEvent):
                raise InputError(f'YAML aliases (*{shorten(event.anchor, 40)}) are not allowed '
                                 f'(line {event.start_mark.line + 1}): write the value out')
            if isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
                depth += 1
                if depth > MAX_DEPTH:
                    raise InputError(f'nested more than {MAX_DEPTH} levels deep (line '
                                     f'{event.start_mark.line + 1})')
            elif isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
                depth -= 1
    except yaml.YAMLError as exc:
        raise InputError(f'not valid YAML: {shorten(str(exc), 300)}') from None


def shorten(value: str, limit: int = 60) -> str:
    """str(value) on one line (whitespace runs as one space), cut to `limit` characters
    with an ellipsis: for error lines.
    """
    text = ' '.join(str(value).split())
    return text if len(text) <= limit else text[:limit - 3] + '...'
