"""Bags written by rosbag2 itself (its own test resources, test/data/rosbag2): described as
`ros2 bag info` describes them, read whole, refused for replay where no type is known here.
"""

import os
import subprocess
import sys

import pytest
import yaml

from conftest import DATA_DIR
from curve_formation.bags.bag import (
    BagError,
    describe_bag,
    format_bag_info,
    read_raw,
)


BAGS = DATA_DIR / 'rosbag2'
ALL = sorted(p.relative_to(BAGS) for p in BAGS.glob('*/*') if p.is_dir())
UNREADABLE = {'wrong_rmw_test'}   # serialization format 'wrong_format': no reader decodes it


def metadata(bag):
    return yaml.safe_load((BAGS / bag / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']


def test_the_bags_cover_every_metadata_version_rosbag2_wrote_before_ours():
    assert {metadata(bag)['version'] for bag in ALL} == {4, 5, 6, 7, 8}
    assert {metadata(bag)['storage_identifier'] for bag in ALL} == {'mcap', 'sqlite3'}


@pytest.mark.parametrize('bag', ALL, ids=str)
def test_bag_info_tells_what_the_metadata_holds(bag):
    meta = metadata(bag)
    info = describe_bag(BAGS / bag)
    assert info['version'] == meta['version']
    assert info['storage'] == meta['storage_identifier'] == bag.parts[0]
    assert info['files'] == [os.path.basename(f) for f in meta['relative_file_paths']]
    assert info['messages'] == meta['message_count']
    assert {t['topic']: t['count'] for t in info['topics']} == {
        e['topic_metadata']['name']: e['message_count']
        for e in meta['topics_with_message_count']}
    text = format_bag_info(info)
    assert f'Storage id:        {bag.parts[0]}' in text
    assert f'Files:             {", ".join(info["files"])}' in text


def test_bag_info_of_a_version_4_mcap_bag_from_the_command_line():
    proc = subprocess.run([sys.executable, '-m', 'curve_formation.cli', 'bag', 'info',
                           str(BAGS / 'mcap' / 'talker')], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert 'Files:             talker.mcap\nBag size:' in proc.stdout
    assert 'Storage id:        mcap' in proc.stdout
    assert ('Topic: /topic | Type: std_msgs/msg/String | Count: 10 | Serialization Format: cdr'
            ' | QoS: reliable, volatile, keep last 0') in proc.stdout


@pytest.mark.parametrize('bag', ALL, ids=str)
def test_every_message_is_read_whatever_the_metadata_qos(bag):
    """rosbags alone read nothing of 5 of these bags: their metadata offers other QoS than
    their storage files record.
    """
    if bag.name in UNREADABLE:
        with pytest.raises(BagError, match='wrong_format'):
            list(read_raw(BAGS / bag))
        return
    counts = {}
    for conn, _, _ in read_raw(BAGS / bag):
        counts[conn.topic] = counts.get(conn.topic, 0) + 1
    assert counts == {e['topic_metadata']['name']: e['message_count']
                      for e in metadata(bag)['topics_with_message_count']
                      if e['message_count']}


def test_replay_of_a_bag_without_any_known_type_says_so():
    proc = subprocess.run([sys.executable, '-m', 'curve_formation.cli', 'replay',
                           str(BAGS / 'sqlite3' / 'cdr_test'), '--wait', '0'],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert 'skipping /test_topic: message type test_msgs/msg/BasicTypes is not available' \
        in proc.stdout
    assert 'none of its topics has a message type installed here' in proc.stderr
