"""seft's Fast DDS profile (``seft_msgs_py.dds``): the file Fast DDS reads, what it sets, and
that a user's own profile is kept. Its effect on a lossy link is tested over real DDS in
``tests/seft_ros/test_two_hosts.py`` (a run over a 1 % lossy link completes)."""

import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from seft_msgs_py import dds

NS = {'f': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}


def test_the_profile_is_the_default_writer_profile_with_a_short_heartbeat():
    root = ET.parse(dds.profile_path()).getroot()
    writers = root.findall('f:publisher', NS)
    assert len(writers) == 1 and writers[0].get('is_default_profile') == 'true'
    period = writers[0].find('f:times/f:heartbeatPeriod', NS)
    seconds = int(period.find('f:sec', NS).text) + 1e-9 * int(period.find('f:nanosec', NS).text)
    assert seconds == pytest.approx(dds.HEARTBEAT_PERIOD_S)
    assert seconds < 3.0                       # Fast DDS's own default, which it replaces


def test_the_profile_is_named_unless_the_user_named_one():
    env = {}
    assert dds.use_seft_profile(env) == str(dds.profile_path())
    assert env == {dds.PROFILE_ENV: str(dds.profile_path())}
    mine = {dds.PROFILE_ENV: '/lab/my_profiles.xml'}
    assert dds.use_seft_profile(mine) == '/lab/my_profiles.xml'
    assert mine == {dds.PROFILE_ENV: '/lab/my_profiles.xml'}


def test_fast_dds_loads_the_profile_without_complaint(tmp_path):
    """A participant created with the profile named: Fast DDS parses it (a file it cannot
    parse gets an XMLPARSER error on its output, as a broken file is checked to give)."""
    code = ('from seft_msgs_py.dds import use_seft_profile; use_seft_profile(); import rclpy; '
            'rclpy.init(); n = rclpy.create_node("dds_profile_probe"); '
            'n.create_publisher(__import__("std_msgs.msg").msg.String, "probe", 10); '
            'n.destroy_node(); rclpy.shutdown()')
    env = {k: v for k, v in __import__('os').environ.items() if k != dds.PROFILE_ENV}
    env['ROS_LOG_DIR'] = str(tmp_path)
    proc = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                          text=True, timeout=60)
    out = proc.stdout + proc.stderr            # Fast DDS logs its errors on stdout
    assert proc.returncode == 0, out
    assert 'XML' not in out, out
    broken = tmp_path / 'broken.xml'
    broken.write_text(dds.profile_path().read_text().replace('</profiles>', ''))
    env[dds.PROFILE_ENV] = str(broken)
    proc = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                          text=True, timeout=60)
    out = proc.stdout + proc.stderr
    assert 'XMLPARSER' in out and 'broken.xml' in out, out    # the check above can fail
