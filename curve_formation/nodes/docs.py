"""README tables of every node's parameters, topics and QoS, generated from the node modules."""

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
)
from curve_formation.nodes.params import markdown_table


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
}


def topic_table(table):
    rows = ['| | topic | type | QoS | meaning |', '| --- | --- | --- | --- | --- |']
    for direction, topic, msg_type, qos_name, meaning in table:
        meaning = meaning.replace('|', '\\|')
        rows.append(f'| {direction} | `{topic}` | {msg_type} | {QOS_TEXT[qos_name]} | '
                    f'{meaning} |')
    return '\n'.join(rows)


def nodes_markdown():
    """The README's node reference, between its `nodes:begin` and `nodes:end` markers."""
    parts = []
    for name, module in NODES:
        summary = module.__doc__.strip().split('\n', 1)[1].strip().replace('\n', ' ')
        parts.append(f'### `{name}`\n\n{summary}\n\n{topic_table(module.TOPICS)}\n\n'
                     f'{markdown_table(module.PARAMETERS)}')
    return '\n\n'.join(parts)
