"""Which Fast DDS profile a process picks (curve_formation.paths), and what the profiles hold."""

import os
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from curve_formation.nodes.topics import REGISTRY
from curve_formation.paths import DDS_PROFILE, DDS_PROFILE_ENV, DDS_PROFILE_UDP


NS = {'p': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}


def chosen(inherited=None, large_data=False):
    """The profile a fresh process ends up with, given the value it inherited."""
    env = {k: v for k, v in os.environ.items() if k != DDS_PROFILE_ENV}
    if inherited is not None:
        env[DDS_PROFILE_ENV] = inherited
    code = ('import os; from curve_formation.paths import use_dds_profile; '
            f'use_dds_profile(large_data={large_data}); print(os.environ["{DDS_PROFILE_ENV}"])')
    return subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                          text=True, check=True).stdout.strip()


@pytest.mark.parametrize('inherited', [None, str(DDS_PROFILE), str(DDS_PROFILE_UDP)])
def test_each_process_picks_its_own_profile_unless_the_user_chose_one(inherited):
    assert chosen(inherited) == str(DDS_PROFILE_UDP)
    assert chosen(inherited, large_data=True) == str(DDS_PROFILE)


def test_a_profile_the_user_chose_is_kept(tmp_path):
    mine = str(tmp_path / 'site.xml')
    assert chosen(mine) == mine
    assert chosen(mine, large_data=True) == mine


def transports(path):
    root = ET.parse(path).getroot()
    kinds = {d.find('p:transport_id', NS).text: d.find('p:type', NS).text
             for d in root.iterfind('.//p:transport_descriptor', NS)}
    participant = root.find('.//p:participant', NS)
    assert participant.get('is_default_profile') == 'true'
    assert participant.find('.//p:useBuiltinTransports', NS).text == 'false'
    return [kinds[t.text] for t in participant.iterfind('.//p:userTransports/p:transport_id', NS)]


def test_only_the_camera_profile_uses_shared_memory():
    assert transports(DDS_PROFILE) == ['SHM', 'UDPv4']
    assert transports(DDS_PROFILE_UDP) == ['UDPv4']


def writer_profiles(path):
    return sorted(profile.get('profile_name') for profile in
                  ET.parse(path).getroot().iterfind('p:data_writer', NS))


def test_writer_profiles_name_topics_of_the_interface_the_same_in_both_profiles():
    """A data_writer profile applies to the topic of its name (rmw_fastrtps): a renamed topic
    would lose it without a word.
    """
    names = writer_profiles(DDS_PROFILE_UDP)
    assert names and names == writer_profiles(DDS_PROFILE)
    assert set(names) <= set(REGISTRY), names


def test_participants_announce_themselves_every_half_second():
    """A participant that starts discovers the running ones at their next announcement
    (Fast DDS's default period: 3 s, a run's start waited up to that per node process).
    """
    for path in (DDS_PROFILE, DDS_PROFILE_UDP):
        participant = ET.parse(path).getroot().find('.//p:participant', NS)
        period = participant.find('.//p:discovery_config/p:leaseAnnouncement', NS)
        assert (int(period.find('p:sec', NS).text), int(period.find('p:nanosec', NS).text)) \
            == (0, 500_000_000), path
