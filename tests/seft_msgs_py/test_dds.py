"""seft's Fast DDS profile (``seft_msgs_py.dds``): the file Fast DDS reads, what it sets, and
that a user's own profile is kept. Its effect on a lossy link is tested over real DDS in
``tests/seft_ros/test_two_hosts.py`` (a run over a 1 % lossy link completes)."""

from pathlib import Path
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from seft_msgs_py import dds
from seft_msgs_py.errors import SeftError

NS = {'f': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}


def test_the_profile_is_the_default_writer_profile_with_a_short_heartbeat():
    root = ET.parse(dds.profile_path()).getroot()
    writers = root.findall('f:publisher', NS)
    assert len(writers) == 1 and writers[0].get('is_default_profile') == 'true'
    period = writers[0].find('f:times/f:heartbeatPeriod', NS)
    seconds = int(period.find('f:sec', NS).text) + 1e-9 * int(period.find('f:nanosec', NS).text)
    assert seconds == pytest.approx(dds.HEARTBEAT_PERIOD_S)
    assert seconds < 3.0                       # Fast DDS's own default, which it replaces


def test_the_profile_asks_for_large_receive_buffers():
    root = ET.parse(dds.profile_path()).getroot()
    participants = root.findall('f:participant', NS)
    assert len(participants) == 1 and participants[0].get('is_default_profile') == 'true'
    size = int(participants[0].find('f:rtps/f:listenSocketBufferSize', NS).text)
    assert size == dds.RECEIVE_BUFFER_BYTES
    assert size >= 4 * 212992                  # Linux's usual default (net.core.rmem_default)


def test_the_profile_announces_a_new_participant_for_two_seconds():
    root = ET.parse(dds.profile_path()).getroot()
    first = root.find('f:participant/f:rtps/f:builtin/f:discovery_config/'
                      'f:initialAnnouncements', NS)
    count = int(first.find('f:count', NS).text)
    period = first.find('f:period', NS)
    seconds = int(period.find('f:sec', NS).text) + 1e-9 * int(period.find('f:nanosec', NS).text)
    assert (count, seconds) == (dds.INITIAL_ANNOUNCEMENTS,
                                pytest.approx(dds.INITIAL_ANNOUNCEMENT_PERIOD_S))
    assert count * seconds >= 2.0               # Fast DDS's own: 5 every 0.1 s


def test_a_realtime_run_starts_after_the_profiles_announcements():
    """The rig takes sample 0 of a real-time run DISCOVERY_SETTLE_S after the graph's last
    node was heard: longer than the profile's initial announcements last (a node's publish
    was blocked for 21-150 ms while they went on), by 0.2 s."""
    root = ET.parse(dds.profile_path()).getroot()
    first = root.find('f:participant/f:rtps/f:builtin/f:discovery_config/'
                      'f:initialAnnouncements', NS)
    period = first.find('f:period', NS)
    window = int(first.find('f:count', NS).text) * (
        int(period.find('f:sec', NS).text) + 1e-9 * int(period.find('f:nanosec', NS).text))
    assert dds.DISCOVERY_SETTLE_S == pytest.approx(window + 0.2)
    from seft_plant_sim import rig_node
    assert rig_node.DISCOVERY_SETTLE_S is dds.DISCOVERY_SETTLE_S


def test_the_profile_is_named_unless_the_user_named_one():
    env = {}
    assert dds.use_seft_profile(env) == str(dds.profile_path())
    assert env == {dds.PROFILE_ENV: str(dds.profile_path())}
    mine = {dds.PROFILE_ENV: '/lab/my_profiles.xml'}
    assert dds.use_seft_profile(mine) == '/lab/my_profiles.xml'
    assert mine == {dds.PROFILE_ENV: '/lab/my_profiles.xml'}


def test_a_missing_profile_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setattr(dds, 'profile_path', lambda: tmp_path / 'fastdds_profile.xml')
    env = {}
    with pytest.raises(SeftError, match=r"fastdds_profile.xml: seft's Fast DDS profile is "
                                        'missing'):
        dds.use_seft_profile(env)
    assert env == {}
    assert dds.use_seft_profile({dds.PROFILE_ENV: 'mine.xml'}) == 'mine.xml'


def _probe(env):
    """Start a participant with a subscription in a process of its own; return its output
    and the receive buffers of its UDP sockets [bytes] (``ss``: the kernel's doubled size)."""
    code = (
        'import os, subprocess, time\n'
        'from seft_msgs_py.dds import use_seft_profile\n'
        'use_seft_profile()\n'
        'import rclpy\n'
        'from std_msgs.msg import String\n'
        'rclpy.init()\n'
        'n = rclpy.create_node("dds_profile_probe")\n'
        'n.create_subscription(String, "probe", lambda m: None, 10)\n'
        'time.sleep(0.3)\n'
        'out = subprocess.run(["ss", "-ulmnp"], capture_output=True, text=True).stdout\n'
        'lines = out.splitlines()\n'
        'me = f"pid={os.getpid()},"\n'
        'for i, line in enumerate(lines[:-1]):\n'
        '    if me in line:\n'
        '        print("RB", lines[i + 1].split("rb")[1].split(",")[0])\n'
        'n.destroy_node()\n'
        'rclpy.shutdown()\n')
    proc = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                          text=True, timeout=60)
    out = proc.stdout + proc.stderr            # Fast DDS logs its errors on stdout
    buffers = [int(line.split()[1]) for line in proc.stdout.splitlines()
               if line.startswith('RB ')]
    return proc.returncode, out, buffers


def test_fast_dds_loads_the_profile_and_applies_it(tmp_path, ros_env):
    """A participant created with the profile named: Fast DDS parses it (a file it cannot
    parse gets an XMLPARSER error on its output, as a broken file is checked to give) and its
    sockets get the receive buffer asked for (capped by the kernel at net.core.rmem_max)."""
    if shutil.which('ss') is None:
        pytest.skip('iproute2 (ss) is not installed')
    env = {k: v for k, v in ros_env.items() if k != dds.PROFILE_ENV}
    # SUBNET, as the hosts of a split run (tools/hosts.sh): with LOCALHOST rmw_fastrtps sets
    # up its own localhost-only transport, which keeps the system's buffers (a run on one
    # host goes over shared memory)
    env.update(ROS_LOG_DIR=str(tmp_path), ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET')
    code, out, buffers = _probe(env)
    assert code == 0, out
    assert 'XML' not in out, out
    rmem_max = int(Path('/proc/sys/net/core/rmem_max').read_text())
    rmem_default = int(Path('/proc/sys/net/core/rmem_default').read_text())
    asked = 2 * min(dds.RECEIVE_BUFFER_BYTES, rmem_max)   # the kernel doubles what it grants
    assert buffers and max(buffers) == asked, (buffers, asked)
    # without the profile the same sockets keep the system's default (the check can fail)
    plain = tmp_path / 'plain.xml'
    plain.write_text('<?xml version="1.0" encoding="UTF-8" ?>\n<profiles xmlns='
                     '"http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"></profiles>\n')
    env[dds.PROFILE_ENV] = str(plain)
    code, out, buffers = _probe(env)
    assert code == 0 and buffers, out
    if asked > rmem_default:
        assert max(buffers) < asked, (buffers, asked)
    broken = tmp_path / 'broken.xml'
    broken.write_text(dds.profile_path().read_text().replace('</profiles>', ''))
    env[dds.PROFILE_ENV] = str(broken)
    _, out, _ = _probe(env)
    assert 'XMLPARSER' in out and 'broken.xml' in out, out    # the first check can fail
