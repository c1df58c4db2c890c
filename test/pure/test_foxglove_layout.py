"""The Foxglove layout shipped for a run's bag (config/foxglove_layout.json) shows only what a
run records: every topic it names is in the bags `run --bag` writes of the arena demo.
"""

import json
import re

from conftest import CONFIG_DIR
from curve_formation.nodes import topics


def named_topics(value):
    """Every '/topic' the layout names (panel topics, plot paths up to their field)."""
    found = set()
    if isinstance(value, dict):
        for key, item in value.items():
            if isinstance(key, str) and key.startswith('/'):
                found.add(key)
            found |= named_topics(item)
    elif isinstance(value, list):
        for item in value:
            found |= named_topics(item)
    elif isinstance(value, str) and value.startswith('/'):
        found.add(re.split(r'\.', value, maxsplit=1)[0])
    return found


def test_the_layout_draws_only_recorded_topics_and_the_curve_markers_and_poses():
    layout = json.loads((CONFIG_DIR / 'foxglove_layout.json').read_text())
    assert {'configById', 'layout'} <= set(layout)
    panels = set(layout['configById'])
    placed = set(re.findall(r'[\w ]+![\w]+', json.dumps(layout['layout'])))
    assert placed == panels, (placed, panels)
    named = named_topics(layout['configById'])
    recorded = {t.name for t in topics.recorded(9)}
    assert named <= recorded, named - recorded
    assert {'/formation/markers', '/robot_1/pose', '/robot_9/pose'} <= named
    assert {'/formation/markers', '/formation/robot_poses'} <= recorded
