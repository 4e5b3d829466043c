"""The UDP bridge's byte layout: sizes, offsets, round trips, rejections, the sequence filter,
and the page's tables."""

from pathlib import Path
import re
import struct

import pytest

from seft_plant_sim import udp_layout as ul

ROOT = Path(__file__).resolve().parents[2]


def command(**changes):
    values = dict(kind=ul.KIND_COMMAND, flags=ul.FLAG_START, session=7, sequence=9, sample=42,
                  source=42, value=-0.125, dt_ns=2_000_000, n_steps=1000,
                  command_kind=ul.COMMAND_VALVE)
    values.update(changes)
    return ul.ToController(**values)


def measurement(**changes):
    values = dict(kind=ul.KIND_MEASUREMENT, state=ul.STATE_RUNNING, session=7, sequence=3,
                  sample=42, force_N=101.5, displacement_m=4.8e-4, velocity_m_s=-1e-3,
                  acceleration_m_s2=0.25, command=0.05, held_source=41, reason=0, late=1,
                  lost=2, duplicate=3, reordered=4, bad=5, latency_sources=(41, 40) + (-1,) * 6,
                  latency_s=(6.5e-4, 7e-4) + (0.0,) * 6)
    values.update(changes)
    return ul.ToPC(**values)


def test_sizes_and_fixed_offsets():
    assert (ul.TO_CONTROLLER_SIZE, ul.TO_PC_SIZE) == (60, 224)
    b = ul.encode(command())
    assert b[:4] == b'SEFT' and b[4] == ul.LAYOUT_VERSION == 1 and b[5] == ul.KIND_COMMAND
    # big-endian at the documented offsets (what LabVIEW or C reads)
    assert struct.unpack_from('>H', b, 6)[0] == ul.FLAG_START
    assert struct.unpack_from('>II', b, 8) == (7, 9)
    assert struct.unpack_from('>qqd', b, 16) == (42, 42, -0.125)
    assert struct.unpack_from('>qqB', b, 40) == (2_000_000, 1000, ul.COMMAND_VALVE)
    assert b[57:] == b'\0\0\0'
    m = ul.encode(measurement())
    assert struct.unpack_from('>q5d', m, 16) == (42, 101.5, 4.8e-4, -1e-3, 0.25, 0.05)
    assert struct.unpack_from('>qH', m, 64) == (41, 0)
    assert struct.unpack_from('>5I', m, 76) == (1, 2, 3, 4, 5)
    assert struct.unpack_from('>8q8d', m, 96) == ((41, 40) + (-1,) * 6 + (6.5e-4, 7e-4)
                                                 + (0.0,) * 6)


def test_round_trips():
    assert ul.decode_to_controller(ul.encode(command())) == command()
    assert ul.decode_to_pc(ul.encode(measurement())) == measurement()
    hb = command(kind=ul.KIND_HEARTBEAT, flags=ul.FLAG_SAFE | ul.FLAG_END, sample=-1,
                 source=-1, value=0.0)
    assert ul.decode_to_controller(ul.encode(hb)) == hb


@pytest.mark.parametrize('edit, message', [
    (lambda b: b[:-1], 'datagram to the controller: 59 bytes, expected 60'),
    (lambda b: b + b'\0', 'datagram to the controller: 61 bytes, expected 60'),
    (lambda b: b'SEFX' + b[4:], "datagram to the controller: magic b'SEFX', expected b'SEFT'"),
    (lambda b: b[:4] + b'\x02' + b[5:], 'datagram to the controller: layout version 2, '
     'expected 1'),
    (lambda b: b[:5] + b'\x03' + b[6:], 'datagram to the controller: kind 3, expected one of '
     '1, 2'),
])
def test_a_wrong_datagram_is_rejected_naming_why(edit, message):
    with pytest.raises(ul.DatagramError, match=f'^{re.escape(message)}$'):
        ul.decode_to_controller(edit(ul.encode(command())))


def test_a_wrong_datagram_to_the_pc_is_rejected():
    with pytest.raises(ul.DatagramError, match=r'^datagram to the PC: 60 bytes, expected 224$'):
        ul.decode_to_pc(ul.encode(command()))
    with pytest.raises(ul.DatagramError, match=r'kind 1, expected one of 3, 4$'):
        b = ul.encode(measurement())
        ul.decode_to_pc(b[:5] + b'\x01' + b[6:])


def test_sequence_filter_applies_in_order_only():
    f = ul.SequenceFilter()
    taken = [s for s in (1, 2, 2, 4, 3, 5, 9, 6, 10) if f.take(s)]
    assert taken == [1, 2, 4, 5, 9, 10]
    assert (f.duplicate, f.reordered, f.lost) == (1, 2, 1 + 3)
    f.reset()
    assert f.take(1) and (f.duplicate, f.reordered, f.lost) == (0, 0, 0)


def test_the_page_holds_the_layout_tables():
    page = (ROOT / 'docs' / 'rig_contract.md').read_text()
    assert ul.markdown_tables() in page, 'run tools/gen_rig_contract_docs.py'
    assert '| 96 | int64 | `latency_source_0` |' in ul.markdown_tables()
