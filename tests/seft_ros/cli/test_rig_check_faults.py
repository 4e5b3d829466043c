"""Each wiring fault of ``seft rig-check --inject`` fails exactly the checks it should, and
seft's rigs pass every check (issue 33), on the runs of a rig check recorded in one process
(``rig_check_runs``: seft's real-time plant, its force servo controller and the fault
wrapper; no DDS): fast, and the same numbers every time. ``test_rig_check.py`` runs a few of
them through the node graph.

The expected failures are the contract's, not the wrapper's: a fault of one channel fails
that channel's checks (a stuck displacement also those judged against it); on a rig whose
force loop seft's controller closes (servohydraulic) a force fault makes the loop run away
and the step run ends at the force limit, which every check of the step run reports.
"""

from pathlib import Path
import re

import pytest
from rig_check_runs import check_params, recorded_runs

from seft_msgs_py import rig_contract
from seft_plant_sim.faults import FAULTS, SENSOR_FAULTS
from seft_ros.cli.rig_check import evaluate
from seft_ros.core import rig_check as rc

DOCS = Path(__file__).resolve().parents[3] / 'docs' / 'rig_contract.md'
SAFE = {'safe state: abort', 'safe state: stopped controller', 'safe state: watchdog'}
#: Every check the step run measures.
STEP_RUN = {*rc.SIGNAL_CHECKS, 'swapped fields', 'stuck sensor', 'sensor noise',
            'command timing'}
#: A force loop closed on a faulty force runs away: the step run ends at the force limit.
RUNAWAY = STEP_RUN | SAFE | {'final status'}
_SIGN = {'displacement sign', 'velocity sign', 'acceleration sign'}
_DERIVED = {'velocity sign', 'velocity scale', 'acceleration sign', 'acceleration scale'}

#: fault -> the checks it fails on a force-commanded rig (delay), and on the valve rig.
EXPECTED = {
    'force_reversed': ({'force sign'}, RUNAWAY),
    'force_kN': ({'force scale'}, RUNAWAY),
    'transducer_reversed': (_SIGN, _SIGN),
    'displacement_reversed': ({'displacement sign'},) * 2,
    'displacement_mm': ({'displacement scale'},) * 2,
    'velocity_reversed': ({'velocity sign'},) * 2,
    'velocity_mm_s': ({'velocity scale'},) * 2,
    'acceleration_reversed': ({'acceleration sign'},) * 2,
    'acceleration_g': ({'acceleration scale'},) * 2,
    'acceleration_stuck': ({'acceleration sign', 'acceleration scale', 'stuck sensor'},) * 2,
    'displacement_stuck': ({'displacement sign', 'displacement scale', 'stuck sensor',
                            *_DERIVED},) * 2,
    'swapped_force_displacement': ({'force scale', 'displacement scale', 'swapped fields'},
                                   RUNAWAY),
    'swapped_velocity_acceleration': ({'swapped fields', *_DERIVED},) * 2,
    'force_noise': ({'sensor noise', 'command timing'},) * 2,
    'stamps_ahead': ({'stamps'},) * 2,
    'stamps_off_grid': ({'stamps'},) * 2,
    'slow_clock': ({'clock', 'stamps'},) * 2,
    'no_safe_state': (SAFE,) * 2,
}
#: Words each fault's failing lines say (the likely fault, the figure).
WORDS = {
    'transducer_reversed': ('displacement sign', 'one transducer mounted the other way round'),
    'force_kN': ('force scale', 'kN instead of N?'),
    'displacement_mm': ('displacement scale', 'mm instead of m?'),
    'velocity_mm_s': ('velocity scale', 'mm/s instead of m/s?'),
    'acceleration_g': ('acceleration scale', 'g instead of m/s^2?'),
    'acceleration_reversed': ('acceleration sign', 'the builder would feed back -a'),
    'acceleration_stuck': ('stuck sensor', 'acceleration_m_s2 read a constant'),
    'swapped_velocity_acceleration': ('swapped fields', 'velocity_m_s and acceleration_m_s2 '
                                      'look swapped'),
    'force_noise': ('sensor noise', 'the load cell noise would trip the instability monitor'),
    'stamps_ahead': ('stamps', 'the stamps run 2.0 samples ahead of the samples'),
    'stamps_off_grid': ('stamps', 'stamps off the grid of k dt'),
    'slow_clock': ('clock', "the rig's clock runs slow"),
}


def failed_checks(model, fault, tmp_path, **overrides):
    params = check_params(model, **overrides)
    profile = rc.CheckProfile(dt=params['dt'])
    results = evaluate(recorded_runs(params, profile, tmp_path, fault), params=params,
                       profile=profile, command_kind=rig_contract.command_kind(params))
    assert [r.name for r in results] == list(rc.checks_for(udp_bridge=False))
    return {r.name: r for r in results if not r.passed}


def test_the_table_covers_every_fault():
    assert set(EXPECTED) == set(FAULTS)


@pytest.mark.parametrize('model', ['delay', 'servohydraulic'])
def test_seft_rigs_pass_every_check(model, tmp_path):
    assert failed_checks(model, None, tmp_path) == {}
    # and with a lab's sensor noise (5 N, 2 um, 0.2 mm/s, 0.05 m/s^2)
    assert failed_checks(model, None, tmp_path, noise_force_N=5.0, noise_displacement_m=2e-6,
                         noise_velocity_m_s=2e-4, noise_acceleration_m_s2=0.05) == {}


@pytest.mark.parametrize('fault', list(EXPECTED))
@pytest.mark.parametrize('model', ['delay', 'servohydraulic'])
def test_each_fault_fails_exactly_its_checks(model, fault, tmp_path):
    failed = failed_checks(model, fault, tmp_path)
    expected = EXPECTED[fault][model == 'servohydraulic']
    assert set(failed) == expected, {n: r.measured for n, r in failed.items()}
    if fault in WORDS and expected is not RUNAWAY:
        check, words = WORDS[fault]
        assert words in failed[check].measured, failed[check].measured
    if expected is RUNAWAY:
        assert re.search(r'force limit exceeded.*a force loop closed on a load cell of the '
                         r'wrong sign or unit runs away', failed['force sign'].measured)


def test_the_docs_table_is_the_tests():
    """docs/rig_contract.md's table of the faults says what they do and which checks each
    fails, as measured here."""
    text = DOCS.read_text()
    table = text[text.index('<!-- rig-faults:begin -->'):text.index('<!-- rig-faults:end -->')]
    rows = {}
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip('|').split('|')]
        if len(cells) == 4 and cells[0].startswith('`'):
            rows[cells[0].strip('`')] = cells[1:]
    assert list(rows) == list(FAULTS)
    for name, (what, delay, valve) in rows.items():
        assert what == FAULTS[name].description + (
            '' if name in SENSOR_FAULTS else ' (rig node only)'), name
        for cell, expected in ((delay, EXPECTED[name][0]), (valve, EXPECTED[name][1])):
            if expected is RUNAWAY:
                assert cell == 'runs away: every check of the step run, the safe states, ' \
                    'final status', name
            else:
                assert cell == ', '.join(c for c in rc.CHECKS if c in expected), name


# -- a structure's rigs, each in its namespace ------------------------------------------------

TWO_PIERS = Path(__file__).resolve().parents[3] / 'config' / 'two_piers.yaml'


@pytest.fixture(scope='module')
def piers():
    from seft_ros.cli import api
    from seft_ros.cli.rig_check import structure_rigs
    return structure_rigs(api.build_runs(config=str(TWO_PIERS), overrides={})[0])


def test_each_rig_of_a_structure_is_checked_with_its_own_parameters(piers):
    from seft_msgs_py.graph import Graph
    assert [r for r, _ in piers] == ['pier_a', 'pier_b']
    for rig, p in piers:
        graph = Graph.from_parameters(p)
        assert graph.rigs == (rig,) and graph.rig_nodes() == (f'{rig}/rig',)
        assert graph.measurement(rig).name == f'/{rig}/seft/measurement'
        assert p['force_controller'] == 'specimen_loop_shaping' and p['alpha'] == 0.0
    assert [p['stiffness_N_per_m'] for _, p in piers] == [2.11e5, 3.376e5]


def test_a_rigs_one_dof_structure_commands_the_check_s_reference_force(piers, tmp_path):
    """The builder of a rig's one-DOF structure (its specimen alone) gives the rig-check's
    reference force exactly (paper Eq. 2.5 with alpha 0), as the study's graph does: played
    in lockstep by seft simulate."""
    import numpy as np

    from seft_ros.cli.rig_check import check_parameters, write_force_record
    from seft_ros.core.experiment import simulate
    rig, p = piers[1]
    profile = rc.CheckProfile(dt=p['dt'])
    reference = profile.step_reference()
    record = write_force_record(tmp_path / 'record.csv', reference, profile.dt, p['mass_kg'])
    run = simulate(dict(check_parameters(p, profile, record, reference.size),
                        mode='lockstep'))
    np.testing.assert_array_equal(run.rigs[rig].reference_force_N, reference[:run.n_steps])


@pytest.mark.parametrize('watchdog_s', [0.02, 0.05, 0.5])
def test_both_piers_pass_every_check(piers, watchdog_s, tmp_path):
    """The stiffer pier creeps, valve closed, at 0.28 of its sine's peak velocity: a seft rig
    that passes (core.rig_check.REST_VELOCITY_FRACTION), while a valve held open fails. A
    watchdog of 0.5 s leaves the closed valve a force 2.9-4.0 x the amplitude to hold, and a
    creep in proportion (2.1-2.8 mm/s) that passes; the valve held open, nearly stalled by
    the load pressure (0.55 mm/s on the stiffer pier), fails by the force it still adds."""
    for rig, p in piers:
        p = dict(p, mode='realtime', watchdog_timeout_s=watchdog_s)
        profile = rc.CheckProfile(dt=p['dt'])
        kind = rig_contract.command_kind(p)
        results = evaluate(recorded_runs(p, profile, tmp_path), params=p, profile=profile,
                           command_kind=kind)
        assert [r.measured for r in results if not r.passed] == [], rig
        held = evaluate(recorded_runs(p, profile, tmp_path, 'no_safe_state'), params=p,
                        profile=profile, command_kind=kind)
        assert {r.name for r in held if not r.passed} == SAFE, rig


@pytest.mark.parametrize('model', ['delay', 'servohydraulic'])
def test_a_fault_at_a_later_chance_is_judged_at_its_own_sample(model, tmp_path):
    """A checker that heard the fault's first chance late injects it a cycle or two later
    (``CheckProfile.fault_steps``): the safe state is judged from that sample (the last cycle
    before it, the rig's reaction to it), a seft rig passes and a rig that holds its command
    fails, as at the first chance."""
    p = check_params(model)
    profile = rc.CheckProfile(dt=p['dt'])
    kind = rig_contract.command_kind(p)
    for chance in (1, 2):
        runs = recorded_runs(p, profile, tmp_path, chance=chance)
        results = {r.name: r for r in evaluate(runs, params=p, profile=profile,
                                               command_kind=kind)}
        assert [r.measured for r in results.values() if not r.passed] == [], chance
        for name in SAFE:
            # the recorded rig enters its safe state at the fault's sample: 0.3 ms after
            # the fault (checker's), and for the watchdog its timeout later
            assert -1e-3 < results[name].values['reaction_s'] < 0.06, (chance, name)
        held = evaluate(recorded_runs(p, profile, tmp_path, 'no_safe_state', chance=chance),
                        params=p, profile=profile, command_kind=kind)
        assert {r.name for r in held if not r.passed} == SAFE, chance
