"""The run's seal (``seft_msgs_py.provenance``, issue 42): the token in the clear, the HMAC
against an independent computation with ``hmac``/``hashlib``, what a seal does not survive
(another run, topic, stamp, value, key), the key file's errors, the datagram trailer."""

import hashlib
import hmac
import struct

import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_msgs_py.provenance import (
    MAC_BYTES,
    RunSeal,
    datagram_mac,
    key_of,
    mac_input,
    new_run_token,
    read_key,
    status_id_of_run,
)

TOKEN = '0123456789abcdef'
KEY = b'k' * 32
TOPIC = '/seft/reference_force'


def test_a_run_token_is_sixteen_random_hex_digits():
    tokens = {new_run_token() for _ in range(100)}
    assert len(tokens) == 100
    assert all(len(t) == 16 and int(t, 16) >= 0 for t in tokens)


def test_no_token_no_seal():
    seal = RunSeal('none')
    assert not seal.sealed and seal.frame_id == 'actuator' and seal.label == 'step'
    assert seal.frame_ok('actuator', TOPIC, 0, (1.0,))
    assert not seal.frame_ok('actuator#' + TOKEN, TOPIC, 0, (1.0,))
    assert seal.frame_id_of(TOPIC, 0, (1.0,)) == 'actuator'
    assert RunSeal.from_parameters(parameters.resolve({})).frame_id == 'actuator'


def test_the_token_in_the_clear():
    seal = RunSeal(TOKEN)
    assert seal.frame_id == 'actuator#' + TOKEN and seal.label == 'step#' + TOKEN
    assert seal.frame_ok(b'actuator#' + TOKEN.encode(), TOPIC, 7, (1.0,))
    # another run's token, the plain frame id, a prefix of the token: not this run's
    for other in ('actuator#' + new_run_token(), 'actuator', 'actuator#' + TOKEN[:-1], ''):
        assert not seal.frame_ok(other, TOPIC, 7, (1.0,)), other
    assert seal.label_ok('step#' + TOKEN, '/seft/record/rig', [1.0, 2.0])
    assert not seal.label_ok('step', '/seft/record/rig', [1.0, 2.0])


def test_the_hmac_against_hashlib():
    """The seal of an authenticated message is the first 32 hex digits of HMAC-SHA256 over
    b'seft-seal-1' 0 token 0 topic 0, the stamp (>q) and the values (>d), computed here
    independently."""
    seal = RunSeal(TOKEN, KEY)
    stamp, values = 14_000_000, (-1234.5, 0.25)
    data = (b'seft-seal-1\0' + TOKEN.encode() + b'\0' + TOPIC.encode() + b'\0'
            + struct.pack('>qdd', stamp, *values))
    assert mac_input(TOKEN, TOPIC, stamp, values) == data
    expected = hmac.new(KEY, data, hashlib.sha256).hexdigest()[:32]
    assert seal.seal(TOPIC, stamp, values) == expected
    assert seal.frame_id_of(TOPIC, stamp, values) == 'actuator#' + expected
    assert seal.frame_id == 'actuator#' + '0' * 32 and len(seal.frame_id) == 41
    assert seal.frame_ok('actuator#' + expected, TOPIC, stamp, values)


@pytest.mark.parametrize('change', ['value', 'stamp', 'topic', 'token', 'key', 'plain',
                                    'truncated'])
def test_a_sealed_message_does_not_survive_a_change(change):
    """A replayed or altered message fails: its value, its step, another topic (another
    rig's reference force), another run (token), another test's key."""
    seal = RunSeal(TOKEN, KEY)
    stamp, values = 14_000_000, (250.0,)
    frame = seal.frame_id_of(TOPIC, stamp, values)
    check = {'value': (frame, TOPIC, stamp, (3000.0,), seal),
             'stamp': (frame, TOPIC, stamp + 2_000_000, values, seal),
             'topic': (frame, '/pier_b/seft/reference_force', stamp, values, seal),
             'token': (frame, TOPIC, stamp, values, RunSeal(new_run_token(), KEY)),
             'key': (frame, TOPIC, stamp, values, RunSeal(TOKEN, b'x' * 32)),
             'plain': ('actuator', TOPIC, stamp, values, seal),
             'truncated': (frame[:-1], TOPIC, stamp, values, seal)}[change]
    frame, topic, stamp, values, seal = check
    assert not seal.frame_ok(frame, topic, stamp, values)


def test_a_record_batch_label():
    seal = RunSeal(TOKEN, KEY)
    rows = [3.0, 1.5, -2.0, 4.0, 2.5, -1.0]
    label = seal.label_of('/seft/record/rig', rows)
    assert label.startswith('step#') and len(label) == 5 + 32
    assert seal.label_ok(label, '/seft/record/rig', rows)
    assert not seal.label_ok(label, '/seft/record/rig', rows[:-1] + [1e6])
    assert not seal.label_ok(label, '/seft/record/ground_motion_publisher', rows)


def test_bad_tokens_and_keys(tmp_path):
    for bad in ('0123', 'XYZ456789abcdefg', '0123456789ABCDEF'):
        with pytest.raises(ParameterError, match=rf"^parameter run_token='{bad}': expected 16 "
                           r"hex digits \(seft run draws one per run\) or 'none'$"):
            RunSeal(bad)
    with pytest.raises(ParameterError, match=r"^parameter message_auth='hmac': expected a "
                       'run_token'):
        RunSeal('none', KEY)
    with pytest.raises(ParameterError, match=r"^parameter auth_key_file='none': "
                       r"message_auth hmac needs the file of the test's shared key$"):
        key_of({'message_auth': 'hmac', 'auth_key_file': 'none'})
    missing = tmp_path / 'missing.key'
    with pytest.raises(ParameterError, match=rf"^parameter auth_key_file='{missing}': cannot "
                       'read it'):
        read_key(str(missing))
    short = tmp_path / 'short.key'
    short.write_text('abc\n')
    with pytest.raises(ParameterError, match=rf"^parameter auth_key_file='{short}': 3 bytes, "
                       r'expected a key of at least 16 \(e\.g\. 64 hex digits\)$'):
        read_key(str(short))
    good = tmp_path / 'good.key'
    good.write_text('  ' + 'ab' * 32 + '\n')
    assert read_key(str(good)) == b'ab' * 32
    assert key_of({'message_auth': 'hmac', 'auth_key_file': str(good)}) == b'ab' * 32
    assert key_of({'message_auth': 'token', 'auth_key_file': str(missing)}) is None


def test_the_datagram_trailer():
    data = bytes(range(60))
    mac = datagram_mac(KEY, data)
    assert len(mac) == MAC_BYTES == 16
    assert mac == hmac.new(KEY, data, hashlib.sha256).digest()[:16]
    assert datagram_mac(KEY, data[:-1] + b'\0') != mac


STATUS_TOPIC = '/seft/status'


def _status(name='rig', state='aborted', message='watchdog', level=2, hardware_id='seft',
            **values):
    """A status report's fields (an object like ``DiagnosticStatus``)."""
    class KV:
        def __init__(self, key, value):
            self.key, self.value = key, value

    class Status:
        pass
    msg = Status()
    msg.name, msg.message, msg.level, msg.hardware_id = name, message, level, hardware_id
    msg.values = [KV('state', state)] + [KV(k, str(v)) for k, v in values.items()]
    return msg


def test_a_status_report_seal():
    """A status report's hardware id: 'seft' without a token; 'seft#' + token in the clear;
    with the key, the first 32 hex digits of HMAC-SHA256 over b'seft-status-1' 0 token 0
    topic 0, the level (one byte), then name, message, keys and values each with its UTF-8
    length (>I), computed here independently."""
    plain = RunSeal('none')
    assert plain.seal_status(_status(), STATUS_TOPIC).hardware_id == 'seft'
    assert plain.status_ok(_status(), STATUS_TOPIC)
    assert not plain.status_ok(_status(hardware_id='seft#' + TOKEN), STATUS_TOPIC)
    clear = RunSeal(TOKEN)
    assert clear.seal_status(_status(), STATUS_TOPIC).hardware_id == 'seft#' + TOKEN
    assert clear.status_ok(_status(hardware_id='seft#' + TOKEN), STATUS_TOPIC)
    for other in ('seft', 'seft#' + new_run_token(), 'seft#' + TOKEN[:-1], 'x#' + TOKEN):
        assert not clear.status_ok(_status(hardware_id=other), STATUS_TOPIC), other
    keyed = RunSeal(TOKEN, KEY)
    msg = keyed.seal_status(_status(step=7, published=7), STATUS_TOPIC)
    field = [b'rig', b'watchdog', b'state', b'aborted', b'step', b'7', b'published', b'7']
    data = (b'seft-status-1\0' + TOKEN.encode() + b'\0' + STATUS_TOPIC.encode() + b'\0'
            + bytes([2]) + b''.join(struct.pack('>I', len(f)) + f for f in field))
    expected = hmac.new(KEY, data, hashlib.sha256).hexdigest()[:32]
    assert msg.hardware_id == 'seft#' + expected
    assert keyed.status_ok(msg, STATUS_TOPIC)
    assert keyed.status_ok(_status(level=b'\x02', hardware_id=msg.hardware_id, step=7,
                                   published=7), STATUS_TOPIC)      # rclpy's byte level
    # the token in the clear, another word, another node, another topic, another key
    assert not keyed.status_ok(_status(hardware_id='seft#' + TOKEN, step=7, published=7),
                               STATUS_TOPIC)
    for changed in (_status(message='watchdog!', hardware_id=msg.hardware_id, step=7,
                            published=7),
                    _status(name='pier_a/rig', hardware_id=msg.hardware_id, step=7,
                            published=7),
                    _status(state='done', hardware_id=msg.hardware_id, step=7, published=7),
                    _status(hardware_id=msg.hardware_id, step=7, published=8)):
        assert not keyed.status_ok(changed, STATUS_TOPIC)
    assert not keyed.status_ok(msg, '/pier_a/seft/status')
    assert not RunSeal(TOKEN, b'j' * 32).status_ok(msg, STATUS_TOPIC)
    assert not RunSeal(new_run_token(), KEY).status_ok(msg, STATUS_TOPIC)


def test_a_status_seal_by_its_form():
    """Without the key (the bag reader): the token itself, or 32 hex digits with hmac."""
    assert status_id_of_run('seft#' + TOKEN, TOKEN, 'token')
    assert not status_id_of_run('seft#' + new_run_token(), TOKEN, 'token')
    assert not status_id_of_run('seft', TOKEN, 'token')
    assert status_id_of_run('seft', 'none', 'token')
    assert not status_id_of_run('seft#' + TOKEN, 'none', 'token')
    assert status_id_of_run('seft#' + 'ab' * 16, TOKEN, 'hmac')
    for other in ('seft#' + TOKEN, 'seft#' + 'ab' * 15, 'seft#' + 'AB' * 16, 'seft'):
        assert not status_id_of_run(other, TOKEN, 'hmac'), other
