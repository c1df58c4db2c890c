"""Reference tables generated from the code: every node's parameters, topics and QoS
(docs/nodes.md, from the node modules) and every controller setting of an experiment file
(docs/experiments.md, from core.controller.settings).
"""

from collections.abc import Sequence
import math
from typing import Any

from curve_formation.core.controller.settings import SETTINGS
from curve_formation.nodes import (
    camera_tracker,
    curve_server,
    fake_arena,
    fake_camera,
    fake_robot,
    formation_controller,
    qos,
    recorder,
    robot_bridge,
    topics,
)
from curve_formation.nodes.params import markdown_table
from curve_formation.nodes.topics import Use


NODES = (('formation_controller', formation_controller),
         ('curve_server', curve_server),
         ('fake_robot', fake_robot),
         ('fake_arena', fake_arena),
         ('robot_bridge', robot_bridge),
         ('formation_recorder', recorder),
         ('camera_tracker', camera_tracker),
         ('fake_camera', fake_camera))

QOS_TEXT = {
    'SENSOR': 'sensor data (best effort, keep last 5)',
    'COMMAND': f'reliable, keep last {qos.COMMAND.depth}',
    'STATE': f'reliable, keep last {qos.STATE.depth}',
    'LATCHED': f'reliable, transient local, keep last {qos.LATCHED.depth}',
    'EVENTS': f'reliable, keep last {qos.EVENTS.depth}',
    'ROLL_CALL': 'reliable, transient local, keep all',
    'IMAGE': f'best effort, keep last {qos.IMAGE.depth}',
    'ANY_PUBLISHER': 'any publisher: read best effort and reliable, volatile',
}


def topic_table(uses: Sequence[Use]) -> str:
    """Markdown table of a node's topics (topics.Use rows), types and QoS from the registry."""
    rows = ['| | topic | type | QoS | meaning |', '| --- | --- | --- | --- | --- |']
    for use in uses:
        topic = topics.REGISTRY[use.name]
        meaning = (use.meaning or topic.meaning).replace('|', '\\|')
        shown_type = topic.type_name.replace('/msg/', '/')
        profile = topic.spec.qos_name if use.direction == 'pub' else topic.spec.reader_qos_key
        rows.append(f'| {use.direction} | `{use.shown_name}` | {shown_type} | '
                    f'{QOS_TEXT[profile]} | {meaning} |')
    return '\n'.join(rows)


def nodes_markdown() -> str:
    """The node reference in docs/nodes.md, between its `nodes:begin` and `nodes:end`
    markers.
    """
    parts = []
    for name, module in NODES:
        summary = (module.__doc__ or '').strip().split('\n', 1)[1].strip().replace('\n', ' ')
        parts.append(f'### `{name}`\n\n{summary}\n\n{topic_table(module.TOPICS)}\n\n'
                     f'{markdown_table(module.PARAMETERS)}')
    return '\n\n'.join(parts)


def _shown(value: Any) -> str:
    """A setting's value as an experiment file writes it."""
    if isinstance(value, float) and math.isinf(value):
        return '.inf'
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, tuple):
        return '[' + ', '.join(_shown(v) for v in value) + ']'
    return f'{value:g}' if isinstance(value, float) else str(value)


def settings_markdown() -> str:
    """The controller settings' table in docs/experiments.md, between its `settings:begin`
    and `settings:end` markers: key, default, unit, range, meaning, node parameter.
    """
    rows = ['| key | default | unit | range | meaning | parameter |',
            '| --- | --- | --- | --- | --- | --- |']
    for setting in SETTINGS.values():
        bounds = []
        if setting.choices:
            bounds.append(' or '.join(_shown(c) for c in setting.choices))
        if setting.low is not None:
            bounds.append(f'>= {setting.low:g}')
        if setting.above is not None:
            bounds.append(f'> {setting.above:g}')
        if setting.high is not None:
            bounds.append(f'<= {setting.high:g}')
        if setting.unlimited:
            bounds.append('.inf = no limit')
        default = 'required' if setting.required else _shown(setting.default)
        meaning = setting.meaning.replace('|', '\\|')
        rows.append(f'| `{setting.key}` | `{default}` | {setting.unit} | {", ".join(bounds)} | '
                    f'{meaning} | `{setting.parameter}` |')
    return '\n'.join(rows)
