"""The node reference (docs/nodes.md) is generated from the code; a run records the topics it
lists; the README's example experiment is valid and settles.
"""


import pytest

from conftest import ROOT
from curve_formation.nodes import docs, topics


NODE_REFERENCE = ROOT / 'docs' / 'nodes.md'


GENERATED = [   # (page, marker, the table as the code makes it, the command that prints it)
    ('nodes.md', 'nodes', docs.nodes_markdown, 'curve-formation nodes-doc'),
    ('experiments.md', 'settings', docs.settings_markdown,
     'curve-formation nodes-doc --settings'),
]


@pytest.mark.parametrize('page, marker, generated, command', GENERATED,
                         ids=[g[0] for g in GENERATED])
def test_a_reference_table_is_the_generated_one(page, marker, generated, command):
    text = (NODE_REFERENCE.parent / page).read_text()
    begin, end = f'<!-- {marker}:begin -->\n', f'\n<!-- {marker}:end -->'
    assert begin in text and end in text, f'docs/{page} lacks the {marker} markers'
    current = text.split(begin, 1)[1].split(end, 1)[0]
    assert current == generated(), f'docs/{page} is stale: regenerate with `{command}`'


def test_a_run_records_every_robots_topics_once_with_their_registered_types():
    recorded = topics.recorded(3)
    names = [t.name for t in recorded]
    assert len(names) == len(set(names)) == 9 + 6 * 3   # markers, robot_poses, fleet, preflight
    assert '/robot_3/cmd_vel' in names and '/formation/curve' in names
    assert topics.REGISTRY['cmd_vel'].type_name == 'geometry_msgs/msg/Twist'
    with_images = [t.name for t in topics.recorded(3, images=True)]
    assert set(with_images) - set(names) == {topics.CAMERA_IMAGE, topics.CAMERA_POSES}


def test_the_readme_example_experiment_is_valid_and_settles(tmp_path):
    """The minimal experiment the README shows passes check and settles in the simulator."""
    from curve_formation.core.config.loading import load_experiment
    from curve_formation.core.record.metrics import result_metrics
    from curve_formation.core.sim.batch import simulate
    text = (NODE_REFERENCE.parent.parent / 'README.md').read_text()
    begin = text.index('```yaml\nname: my_loop')
    path = tmp_path / 'my_loop.yaml'
    path.write_text(text[begin + len('```yaml\n'):text.index('```', begin + 7)])
    metrics = result_metrics(simulate(load_experiment(path)))
    assert metrics['all_settled'], metrics['phases']
