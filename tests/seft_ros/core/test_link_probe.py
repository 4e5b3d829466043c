"""NTP-style ping numerics and the playout delay / preview chosen from them."""

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_ros.cli.link import decide
from seft_ros.core.link_probe import (
    PLAYOUT_MARGIN_S,
    PingSample,
    estimate,
    playout_steps,
    preview_steps,
)

MS = 1_000_000


def _pings(n, out_ms, back_ms, offset_ms, jitter_ms=0.0, seed=1):
    """Pings from A to B and back: one way out_ms, back back_ms (+ uniform jitter), B's
    clock offset_ms ahead of A's, B holding the ping 0.1 ms."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        t1 = 1_000 * MS + i * 25 * MS
        go = out_ms + jitter_ms * rng.uniform(-1, 1)
        ret = back_ms + jitter_ms * rng.uniform(-1, 1)
        t2 = t1 + int((go + offset_ms) * MS)
        t3 = t2 + int(0.1 * MS)
        t4 = t1 + int((go + 0.1 + ret) * MS)
        out.append(PingSample(t1, t2, t3, t4))
    return out


def test_symmetric_link_round_trip_and_offset_exact():
    e = estimate(_pings(40, 5.0, 5.0, offset_ms=37.0))
    assert e.round_trip_s == pytest.approx({'p50': 0.010, 'p99': 0.010, 'max': 0.010},
                                           abs=2e-9)
    assert e.offset_s == pytest.approx(0.037, abs=2e-9)
    assert e.samples == 40


def test_jitter_and_asymmetry_bound_the_offset_error():
    """Jitter +/- 20 % of 20 ms: the least-delayed quarter's median offset stays within half
    the jitter; an asymmetry of a biases the offset by a / 2 (RFC 5905, Sec. 8)."""
    e = estimate(_pings(200, 20.0, 20.0, offset_ms=-50.0, jitter_ms=4.0))
    assert 0.032 < e.round_trip_s['p50'] < 0.048 and e.round_trip_s['max'] <= 0.0481
    assert abs(e.offset_s + 0.050) < 0.002
    skew = estimate(_pings(40, 6.0, 4.0, offset_ms=0.0))
    assert skew.offset_s == pytest.approx(0.001, abs=1e-8)      # (6 - 4) / 2 ms


def test_bad_pings_are_refused():
    with pytest.raises(ParameterError, match='expected at least one ping'):
        estimate([])
    with pytest.raises(ParameterError, match='negative round trip'):
        estimate([PingSample(10 * MS, 0, 0, 5 * MS)])


def test_the_playout_delay_covers_the_measured_round_trip():
    dt = 0.002
    for trip in (0.0, 0.0004, 0.0093, 0.0421, 0.2):
        n = playout_steps(trip, dt)
        assert n * dt >= trip + PLAYOUT_MARGIN_S - 1e-12
        assert (n - 1) * dt < trip + PLAYOUT_MARGIN_S
    assert preview_steps(0.001, dt, at_least=50) == 251         # (0.001 + 0.5) / 0.002
    assert preview_steps(0.2, dt, at_least=50) == 350           # (0.2 + 0.5) / 0.002
    assert preview_steps(0.2, dt, at_least=400) == 400          # a larger one is kept


def test_decide_puts_the_playout_where_the_loop_crosses_hosts():
    p = parameters.resolve({'rig_model': 'servohydraulic', 'mode': 'realtime'})
    assert decide(dict(p, mode='lockstep'), {
        'compute': ['recorder', 'ground_motion_publisher', 'reference_force_builder'],
        'lab': ['force_servo_controller', 'rig']},
        {'lab': {'round_trip_ms': {'p50': 9.0, 'p99': 12.0, 'max': 14.0}}},
        'compute')['network_delay_s'] == 0.0                  # lockstep waits instead
    links = {'lab': {'round_trip_ms': {'p50': 9.0, 'p99': 12.0, 'max': 14.0}}}
    remote = decide(p, {'compute': ['recorder', 'ground_motion_publisher',
                                    'reference_force_builder'],
                        'lab': ['force_servo_controller', 'rig']}, links, 'compute')
    assert remote['playout'] == 'auto'
    assert remote['network_delay_s'] == pytest.approx(0.016)     # ceil((12 + 3) / 2) * 2 ms
    # the publisher follows the rig's /clock, which crosses once: 6 ms + 500 ms
    assert remote['preview_steps'] == 253
    local = decide(p, {'compute': ['recorder', 'ground_motion_publisher'],
                       'lab': ['reference_force_builder', 'force_servo_controller', 'rig']},
                   links, 'compute')
    assert local['playout'] == 'none' and local['network_delay_s'] == 0.0
    # the ground motion crosses twice (the clock out, the samples back): 12 ms + 500 ms
    assert local['preview_steps'] == 256
    far = {'lab': {'round_trip_ms': {'p50': 180.0, 'p99': 210.0, 'max': 230.0}}}
    assert decide(p, {'compute': ['recorder', 'ground_motion_publisher'],
                      'lab': ['reference_force_builder', 'force_servo_controller', 'rig']},
                  far, 'compute')['preview_steps'] == 355      # (210 + 500) / 2
    given = decide(dict(p, network_delay_s=0.03), {
        'compute': ['recorder', 'ground_motion_publisher', 'reference_force_builder'],
        'lab': ['force_servo_controller', 'rig']}, links, 'compute')
    assert given['playout'] == 'given' and given['network_delay_s'] == 0.03


def test_a_playout_delay_given_for_a_local_loop_is_dropped():
    p = parameters.resolve({'rig_model': 'servohydraulic', 'mode': 'realtime',
                            'network_delay_s': 0.014})
    local = decide(p, {'compute': ['recorder', 'ground_motion_publisher'],
                       'lab': ['reference_force_builder', 'force_servo_controller', 'rig']},
                   {'lab': {'round_trip_ms': {'p50': 9.0, 'p99': 12.0, 'max': 14.0}}},
                   'compute')
    assert local['network_delay_s'] == 0.0
    assert local['playout'] == 'dropped: the loop does not cross hosts'
