"""The last link to a robot without ROS: wire formats (wire) and byte links (links)."""

import math
import socket
import time

import numpy as np
import pytest

from curve_formation import links, wire
from curve_formation.core.formation.dynamics import body_from_wheels


RADIUS, BASE = 0.015, 0.08


@pytest.mark.parametrize('preset', sorted(wire.PRESETS))
def test_every_preset_reads_back_what_it_writes(preset):
    fmt = wire.PRESETS[preset]
    rng = np.random.default_rng(1)
    for seq, (left, right) in enumerate(rng.uniform(-0.1, 0.1, (50, 2)), 1):
        line = wire.encode(fmt, left, right, seq, RADIUS)
        assert line.endswith(b'\n')
        kind, left_back, right_back, seq_back = wire.decode(fmt, line, RADIUS)
        # written with 3 decimals in rad/s (1.5e-5 m/s at r = 1.5 cm) or 5 in m/s
        assert kind == 'command'
        assert left_back == pytest.approx(left, abs=2e-5)
        assert right_back == pytest.approx(right, abs=2e-5)
        assert seq_back == (seq if '{seq' in fmt.command else None)
    assert wire.decode(fmt, wire.encode_stop(fmt, 7), RADIUS)[0] == 'stop'


def test_mona_serial_writes_wheel_speeds_in_rad_s():
    fmt = wire.PRESETS['mona-serial']
    assert wire.encode(fmt, 0.03, -0.015, 1, RADIUS) == b'set 2.000 -1.000\n'
    assert wire.encode_stop(fmt, 2) == b'stop\n'


@pytest.mark.parametrize('line', [b'', b'\n', b'set 1.0\n', b'set a b\n', b'set nan 1\n',
                                  b'set inf 1\n', b'\xff\xfe\x00\n', b'stop now\n',
                                  b'set 1 2 3\n', b'SET 1 2\n', b'set 1e999 1\n'])
def test_lines_that_are_neither_command_nor_stop_decode_to_none(line):
    assert wire.decode(wire.PRESETS['mona-serial'], line, RADIUS) is None


def test_a_wheel_over_its_limit_scales_both_and_keeps_the_curvature():
    v, w = 0.1, 1.5                        # right wheel would be 0.16 m/s
    left, right = wire.saturated_wheel_speeds(v, w, BASE, 0.08)
    assert max(abs(left), abs(right)) == pytest.approx(0.08)
    v_out, w_out = body_from_wheels(left, right, BASE)
    assert w_out / v_out == pytest.approx(w / v)
    # within the limit: unchanged; no limit: unchanged
    assert body_from_wheels(*wire.saturated_wheel_speeds(0.02, 0.3, BASE, 0.08), BASE) == \
        pytest.approx((0.02, 0.3))
    assert body_from_wheels(*wire.saturated_wheel_speeds(1.0, 3.0, BASE, math.inf), BASE) == \
        pytest.approx((1.0, 3.0))


@pytest.mark.parametrize(('command', 'stop', 'unit', 'says'), [
    ('go {left}\n', 'stop\n', 'rad/s', "lacks ['right']"),
    ('go {left} {right} {speed}\n', 'stop\n', 'rad/s', "unknown fields ['speed']"),
    ('go {left} {right\n', 'stop\n', 'rad/s', "expected '}'"),
    ('go {left} {right}\n', '', 'rad/s', 'stop template is empty'),
    ('go {left} {right}\n', 'go {left} {right}\n', 'rad/s', 'cannot be told apart'),
    ('go {left} {right}\n', 'stop\n', 'rpm', "'rad/s' or 'm/s'"),
])
def test_a_custom_format_that_cannot_work_is_refused_saying_why(command, stop, unit, says):
    with pytest.raises(wire.WireError, match=says.replace('[', r'\[').replace(']', r'\]')):
        wire.wire_format('', command, stop, unit)


def test_a_custom_format_round_trips():
    fmt = wire.wire_format('', 'M,{seq},{left:.2f},{right:.2f};\n', 'M,{seq},X;\n', 'm/s')
    assert wire.decode(fmt, wire.encode(fmt, 0.05, -0.02, 9, RADIUS), RADIUS) == \
        ('command', 0.05, -0.02, 9)
    assert wire.decode(fmt, b'M,10,X;\n', RADIUS) == ('stop', 10)
    with pytest.raises(wire.WireError, match="unknown wire format 'mona'"):
        wire.wire_format('mona')


@pytest.mark.parametrize(('address', 'expected'), [
    ('udp:10.0.0.7:4210', ('udp', ('10.0.0.7', 4210))),
    ('serial:/dev/ttyUSB0', ('serial', '/dev/ttyUSB0')),
    ('pty:/tmp/robot_1', ('pty', '/tmp/robot_1'))])
def test_addresses_parse(address, expected):
    assert links.parse_address(address) == expected


@pytest.mark.parametrize('address', ['udp:host', 'udp::80', 'udp:h:0', 'udp:h:99999',
                                     'serial:', 'tcp:h:1', '/dev/ttyUSB0'])
def test_bad_addresses_are_refused(address):
    with pytest.raises(ValueError, match='expected'):
        links.parse_address(address)


def wait_lines(source, count=1, timeout=2.0):
    got, deadline = [], time.monotonic() + timeout
    while len(got) < count and time.monotonic() < deadline:
        got += source.lines()
        time.sleep(0.002)
    return got


def lines_cross_both_ways(robot, bridge, line):
    """A line from the bridge reaches the robot, and the robot's reply the bridge."""
    try:
        bridge.send(line)
        assert wait_lines(robot) == [line]
        robot.send(b'ok\n')
        assert wait_lines(bridge) == [b'ok\n']
    finally:
        bridge.close()
        robot.close()


def test_udp_link_carries_lines_both_ways():
    robot = links.UdpEndpoint(('127.0.0.1', 0))
    port = robot.socket.getsockname()[1]
    lines_cross_both_ways(robot, links.robot_link(f'udp:127.0.0.1:{port}'),
                          b'set 1.000 2.000\n')


def test_over_long_and_split_lines():
    lines = links._Lines()
    assert lines.feed(b'set 1') == []
    assert lines.feed(b' 2\nst') == [b'set 1 2\n']
    assert lines.feed(b'x' * (links.MAX_LINE + 1)) == []
    assert lines.dropped == 1             # the unterminated run of garbage was dropped
    assert lines.feed(b'op\n') == [b'op\n']
    assert lines.feed(b'y' * (links.MAX_LINE + 1) + b'\nstop\n') == [b'stop\n']
    assert lines.dropped == 2


def test_serial_link_over_a_pseudo_terminal(tmp_path):
    robot = links.robot_endpoint(f'pty:{tmp_path / "robot_1"}')
    lines_cross_both_ways(robot, links.robot_link(f'serial:{tmp_path / "robot_1"}'),
                          b'set 0.500 0.500\n')
    assert not (tmp_path / 'robot_1').exists()


def test_a_serial_port_that_comes_back_is_reopened(tmp_path, monkeypatch):
    """Absent at first (robot off), then present, then gone (cable out), then back."""
    monkeypatch.setattr(links, 'REOPEN_PERIOD', 0.1)
    path = tmp_path / 'robot_1'
    bridge = links.SerialLink(str(path))
    with pytest.raises(links.LinkError, match='No such file'):
        bridge.send(b'stop\n')
    with pytest.raises(links.LinkError, match='No such file'):   # too soon: same error
        bridge.send(b'stop\n')
    robot = links.PtyEndpoint(path)
    deadline = time.monotonic() + 5.0
    while True:   # the bridge reopens its link once REOPEN_PERIOD has passed
        try:
            bridge.send(b'stop\n')
            break
        except links.LinkError:
            assert time.monotonic() < deadline, 'the link was never reopened'
    assert wait_lines(robot) == [b'stop\n'] and bridge.opened == 1
    robot.close()                         # the other end goes away
    with pytest.raises(links.LinkError):
        for _ in range(100):              # a write fails once the pty has hung up
            bridge.send(b'stop\n')
            bridge.lines()
            time.sleep(0.001)
    assert bridge.port is None
    robot = links.PtyEndpoint(path)       # back, on another pty behind the same name
    deadline = time.monotonic() + 2.0
    while True:
        try:
            bridge.send(b'set 1.000 1.000\n')
            break
        except links.LinkError:
            assert time.monotonic() < deadline
            time.sleep(0.02)
    assert wait_lines(robot) == [b'set 1.000 1.000\n'] and bridge.opened == 2
    bridge.close()
    robot.close()


def test_a_udp_robot_that_is_not_there_does_not_break_the_link():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(('127.0.0.1', 0))
        port = probe.getsockname()[1]     # closed again: nobody listens
    bridge = links.robot_link(f'udp:127.0.0.1:{port}')
    for _ in range(3):                    # ICMP port unreachable may fail a later call
        try:
            bridge.send(b'stop\n')
        except links.LinkError as exc:
            assert 'udp 127.0.0.1' in str(exc)
        assert bridge.lines() == []
    bridge.close()


def test_a_firmware_answer_may_carry_the_battery_voltage():
    assert wire.is_reply(b'ok\n') and wire.is_reply('ok 3.71') and wire.is_reply(b'err\n')
    assert not wire.is_reply(b'okay\n') and not wire.is_reply(b'set 1 2\n')
    assert wire.battery(b'ok 3.71\n') == 3.71
    assert wire.battery(b'ok\n') is None and wire.battery('ok nan') is None
    assert wire.battery('ok three') is None and wire.battery('err 3.7') is None
