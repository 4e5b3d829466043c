"""A structure test as a node graph: every rig and its controller in the rig's namespace, over
real DDS in lockstep, checked from the bag on disk against ``simulate``.

Two structures: a two-story building whose first story is the study's specimen on the
servohydraulic rig (one rig, a computational story), and a bridge deck on two piers of
different stiffness, each pier on its own rig, with one builder for both rigs (``central``)
and with one builder beside each rig (``per_rig``).
"""

import json
from pathlib import Path
import re

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
import yaml

from seft_msgs_py import parameters
from seft_ros.analysis.bag import read_run
from seft_ros.analysis.rundata import RunData
from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.experiment import simulate

ROOT = Path(__file__).resolve().parents[2]

TWO_STORY = """\
predictor: model
duration_s: 1.0
structure:
  dofs: [story_1, story_2]
  physical: {story_1: lab}
  story_masses_kg: [52.7, 52.7]
  story_stiffnesses_N_per_m: [2.11e5, 2.11e5]
  story_damping_N_s_per_m: [903.278, 133.4]
rigs:
  lab: {rig_model: servohydraulic}
"""

BRIDGE = """\
predictor: {predictor}
duration_s: 1.0
structure_builders: {builders}
structure:
  dofs: [pier_a, pier_b, deck]
  physical: {{pier_a: pier_a, pier_b: pier_b}}
  mass_matrix_kg: [[52.7, 0, 0], [0, 52.7, 0], [0, 0, 105.4]]
  stiffness_matrix_N_per_m: [[4.22e5, 0, -2.11e5], [0, 5.486e5, -2.11e5],
                             [-2.11e5, -2.11e5, 4.22e5]]
  damping_matrix_N_s_per_m: [[1100, 0, -200], [0, 1100, -200], [-200, -200, 400]]
rigs:
  pier_a: {{force_controller: specimen_loop_shaping}}
  pier_b: {{stiffness_N_per_m: 3.376e5, force_controller: specimen_loop_shaping,
           rig_model: {rig_b}}}
"""


@pytest.fixture(scope='module')
def runner(ros_env, tmp_path_factory):
    """A graph runner in the session's ROS domain (its nodes log under tmp)."""
    import os

    from seft_ros.cli.runner import GraphRunner
    saved = dict(os.environ)
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    r = GraphRunner(int(ros_env['ROS_DOMAIN_ID']))
    yield r
    r.close()
    os.environ.clear()
    os.environ.update(saved)


def _params(tmp_path, text):
    path = tmp_path / 'config.yaml'
    path.write_text(text)
    runs = expand_runs(load_config(path), where=str(path))
    assert len(runs) == 1
    return runs[0]


def _same_run(rd: RunData, sim: RunData) -> None:
    """Bit for bit: every rig's signals and the computational state as recorded."""
    assert rd.n_steps == sim.n_steps
    assert list(rd.rigs) == list(sim.rigs)
    np.testing.assert_array_equal(rd.ground_acceleration_m_s2, sim.ground_acceleration_m_s2)
    for name, rig in rd.rigs.items():
        for attr in ('reference_force_N', 'measured_force_N', 'displacement_m', 'velocity_m_s',
                     'acceleration_m_s2', 'valve_command_V'):
            got, want = getattr(rig, attr), getattr(sim.rigs[name], attr)
            if want is None:
                assert got is None, (name, attr)
                continue
            np.testing.assert_array_equal(got, want, err_msg=f'{name} {attr}')
    assert set(rd.computational) == set(sim.computational)
    for key, values in rd.computational.items():
        np.testing.assert_array_equal(values, sim.computational[key], err_msg=key)


def test_two_story_graph_equals_simulate(runner, tmp_path):
    params = _params(tmp_path, TWO_STORY)
    out = runner.run(params, tmp_path / 'run')
    # (the runner may not hear a short run's last reports: the bag holds them)
    assert out.rig_state in ('done', ''), out.message
    # each node's log and parameters: the rig's nodes in its namespace, with its own file
    logs = sorted(p.name for p in (tmp_path / 'run' / 'logs').glob('*.log'))
    assert logs == ['ground_motion_publisher.log', 'lab.force_servo_controller.log',
                    'lab.rig.log', 'recorder.log', 'reference_force_builder.log']
    assert (tmp_path / 'run' / 'params_lab.yaml').is_file()
    with Reader(out.bag_path) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    n = 500
    for topic in ('/lab/seft/reference_force', '/lab/seft/valve_command',
                  '/lab/seft/measured_force', '/lab/seft/displacement', '/lab/seft/velocity',
                  '/lab/seft/acceleration', '/seft/ground_acceleration'):
        assert counts[topic] == n, topic
    assert counts['/seft/structure_state'] == n - 1      # x_Q[k-1] with each f_r[k], k >= 1
    assert '/seft/measured_force' not in counts
    rd = read_run(out.bag_path)
    assert isinstance(rd, RunData) and rd.stable and rd.abort_reason is None
    assert set(rd.computational) == {'story_2/displacement_m', 'story_2/velocity_m_s',
                                     'story_2/acceleration_m_s2'}
    assert np.isnan(rd.computational['story_2/displacement_m'][-1])
    assert np.ptp(rd.computational['story_2/displacement_m'][:-1]) > 1e-4
    _same_run(rd, simulate(rd.params))


def test_an_opensees_model_stepped_after_the_command_equals_simulate(runner, tmp_path):
    """config/opensees/two_story.yaml with ``step: deferred`` (OpenSees steps to a sample
    after the builder node's command from it is out): the graph's bag equals ``simulate``
    bit for bit, the computational state recorded one sample later (``n - 2`` samples, the
    last two NaN) as OpenSees stepped it."""
    path = ROOT / 'config' / 'opensees' / 'two_story.yaml'
    section = yaml.safe_load(path.read_text())
    section['structure']['opensees'].update(step='deferred', model=str(path.with_suffix('.py')))
    section.update(predictor='model', duration_s=1.0)
    params = _params(tmp_path, yaml.safe_dump(section))
    out = runner.run(params, tmp_path / 'run')
    assert out.rig_state in ('done', ''), out.message
    with Reader(out.bag_path) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts['/seft/structure_state'] == 500 - 2
    rd = read_run(out.bag_path)
    assert rd.stable, rd.abort_reason
    x2 = rd.computational['story_2/displacement_m']
    assert np.all(np.isnan(x2[-2:])) and not np.any(np.isnan(x2[:-2]))
    assert np.ptp(x2[:-2]) > 1e-4
    # OpenSees' step times are the wall clock's (each step's own, in the node's process)
    step_time = rd.computational.pop('opensees/step_time_s')
    assert np.all(step_time[1:-2] > 0)
    sim = simulate(rd.params)
    sim.computational.pop('opensees/step_time_s')
    _same_run(rd, sim)
    # what the builder node's part found before the test (its pushover: the elastic
    # building, no mechanism), carried by its final status in the bag as simulate carries it
    found, sim_found = (r.extra['part_findings']['pushover'] for r in (rd, sim))
    assert found['ran'] and sim_found['ran'] and found['time_s'] > 0.0
    assert found['mechanisms'] == sim_found['mechanisms'] == []


def test_a_calibrated_two_story_graph_equals_simulate(runner, tmp_path):
    """predictor_calibration poles on the first story's rig: the builder node calibrates the
    coupled loop itself (law_calibration.structure_calibration) and gets seft simulate's
    corrections, bit for bit; over 15 s they take NRMS x per story from 1.04 / 0.94 % to
    0.70 / 0.68 % (docs/results/own-actuator.md)."""
    from seft_ros.core.law_calibration import structure_calibration
    def config(calibration):
        (tmp_path / calibration).mkdir()
        return _params(tmp_path / calibration, TWO_STORY.replace(
            'lab: {rig_model: servohydraulic}',
            f'lab: {{rig_model: servohydraulic, predictor_calibration: {calibration}}}'))
    params = config('poles')
    assert list(structure_calibration(params)) == ['lab']
    out = runner.run(params, tmp_path / 'run')
    assert out.rig_state in ('done', ''), out.message
    rd = read_run(out.bag_path)
    assert rd.stable
    _same_run(rd, simulate(rd.params))
    assert not np.array_equal(simulate(config('none')).rigs['lab'].reference_force_N,
                              rd.rigs['lab'].reference_force_N)


@pytest.fixture
def processes(request, runner):
    """How the runner starts the nodes for this test (``node`` unless parametrized)."""
    runner.processes = getattr(request, 'param', 'node')
    yield runner.processes
    runner.processes = 'node'


@pytest.mark.parametrize('builders,predictor,rig_b,processes', [
    ('central', 'model', 'servohydraulic', 'node'),
    ('per_rig', 'model', 'servohydraulic', 'node'),
    ('per_rig', 'model', 'delay', 'node'),
    # one builder for rigs of different delays (20 ms force loop, 10 ms delay rig): each
    # rig's compensator predicts over its own delay
    ('central', 'model', 'delay', 'node'),
    # each pier's builder, controller and rig in one process (seft run --processes loop)
    ('per_rig', 'model', 'servohydraulic', 'loop'),
    ('central', 'model', 'servohydraulic', 'loop'),
], indirect=['processes'])
def test_bridge_on_two_rigs_equals_simulate(runner, tmp_path, builders, predictor, rig_b,
                                            processes):
    params = _params(tmp_path, BRIDGE.format(builders=builders, predictor=predictor,
                                             rig_b=rig_b))
    out = runner.run(params, tmp_path / 'run')
    logs = tmp_path / 'run' / 'logs'
    # the loop processes: a pier's nodes that run in its namespace, each node's log a link
    together = {'pier_a': ['rig', 'force_servo_controller'] + (
                    ['reference_force_builder'] if builders == 'per_rig' else []),
                'pier_b': (['rig'] if rig_b == 'delay' else ['rig', 'force_servo_controller'])
                + (['reference_force_builder'] if builders == 'per_rig' else [])}
    for rig, kinds in together.items():
        alone = processes == 'node' or len(kinds) == 1
        for kind in kinds:
            assert (logs / f'{rig}.{kind}.log').is_symlink() is not alone, (rig, kind)
        assert (logs / f'{rig}.loop.log').exists() is not alone, rig
    assert not (logs / 'recorder.log').is_symlink()
    assert out.rig_state in ('done', ''), out.message
    node_params = json.loads((tmp_path / 'run' / 'outcome.json').read_text())
    assert set(node_params['nodes']) >= {'pier_a/rig', 'pier_b/rig',
                                         'pier_a/force_servo_controller'}
    assert ('pier_b/force_servo_controller' in node_params['nodes']) == (rig_b != 'delay')
    rd = read_run(out.bag_path)
    assert list(rd.rigs) == ['pier_a', 'pier_b']
    # each rig ran with its own specimen: the node parameters in the bag say so
    stiffness = {r: rd.rigs[r].params['stiffness_N_per_m'] for r in rd.rigs}
    assert stiffness == {'pier_a': 2.11e5, 'pier_b': 3.376e5}
    assert rd.extra['parameter_mismatches'] == []
    assert (rd.rigs['pier_b'].valve_command_V is None) == (rig_b == 'delay')
    _same_run(rd, simulate(rd.params))
    if builders == 'per_rig':
        with Reader(out.bag_path) as reader:
            topics = {c.topic for c in reader.connections}
        assert {'/pier_a/seft/structure_state', '/pier_b/seft/structure_state',
                '/pier_a/seft/timing/reference_force_builder'} <= topics


@pytest.mark.parametrize('excitation_input', ['reference_force', 'valve_command'])
def test_an_identification_run_of_the_bridge_equals_simulate(runner, tmp_path,
                                                              excitation_input):
    """seft run of the piers' identification run: each rig alone in its namespace (no
    computational state), every rig excited (closed loop: its reference force is the
    excitation; open loop: its controller node drives the valve with it), bit for bit
    simulate's."""
    text = BRIDGE.format(builders='central', predictor='none', rig_b='servohydraulic')
    params = _params(tmp_path, text + 'excitation: noise\nexcitation_band_low_hz: 2.0\n'
                     f'excitation_input: {excitation_input}\n')
    out = runner.run(params, tmp_path / 'run')
    assert out.rig_state in ('done', ''), out.message
    rd = read_run(out.bag_path)
    assert list(rd.rigs) == ['pier_a', 'pier_b'] and not rd.computational and rd.stable
    _same_run(rd, simulate(rd.params))
    name = 'reference_force_N' if excitation_input == 'reference_force' else 'valve_command_V'
    excited = [getattr(rig, name) for rig in rd.rigs.values()]
    np.testing.assert_array_equal(excited[0], excited[1])     # one excitation for every rig
    assert np.std(excited[0]) > 0
    assert all(np.ptp(rig.displacement_m) > 1e-5 for rig in rd.rigs.values())


def test_a_rig_at_its_limit_ends_every_rig_and_the_bag_reads(runner, tmp_path):
    """Uncompensated, the delay of the force loops destabilises the deck's coupling (negative
    damping): pier b reaches its stroke limit, and every rig ends there, aborted with that
    reason; the bag up to then equals simulate, which stops at the same step. (The
    divergence guard, which would end it first in the builder, off: the rig's own limit is
    the test.)"""
    params = _params(tmp_path, BRIDGE.format(builders='central', predictor='none',
                                             rig_b='delay').replace(
        'duration_s: 1.0', 'duration_s: 3.0\ndivergence_factor: 0.0'))
    sim = simulate(params)
    assert not sim.stable and sim.extra['abort_node'] == 'pier_b/rig'
    assert sim.abort_reason.startswith('stroke limit exceeded at t=')
    out = runner.run(params, tmp_path / 'run')
    rd = read_run(out.bag_path)
    finals = rd.extra['rig_finals']          # the rigs' final reports, from the bag
    assert finals['pier_b/rig']['state'] == 'aborted'
    assert finals['pier_b/rig']['message'] == sim.abort_reason
    assert finals['pier_a/rig']['state'] == 'aborted'
    assert finals['pier_a/rig']['message'] == f'pier_b/rig: {sim.abort_reason}'
    assert out.rig_state in ('aborted', '')
    assert not rd.stable and rd.abort_reason == f'pier_b/rig: {sim.abort_reason}'
    assert rd.unstable_at_s == pytest.approx(sim.n_steps * 0.002)
    _same_run(rd, sim)
    # pier a ended on pier b's abort (it says so), after its samples of every step the run
    # holds: its controller's valve command of the last step too, whichever report came first
    assert finals['pier_a/rig']['ended_by'] == 'pier_b/rig'
    assert 'ended_by' not in finals['pier_b/rig']
    assert int(finals['pier_b/rig']['published']) == sim.n_steps
    with Reader(out.bag_path) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    for topic in ('/pier_a/seft/valve_command', '/pier_a/seft/measured_force',
                  '/pier_a/seft/reference_force', '/pier_b/seft/reference_force'):
        assert counts[topic] >= sim.n_steps, topic
    # a bag without that last valve command (a node lost with it) and with pier a's report
    # first: the run still ended where pier b aborted, named as the cause
    cut = _rewritten(out.bag_path, tmp_path / 'cut', sim.n_steps - 1)
    rd = read_run(cut)
    assert rd.n_steps == sim.n_steps - 1
    assert rd.abort_reason == f'pier_b/rig: {sim.abort_reason}'
    assert rd.extra['abort_node'] == sim.extra['abort_node'] == 'pier_b/rig'
    assert rd.unstable_at_s == pytest.approx(sim.n_steps * 0.002)


def _rewritten(bag, dst, last_step):
    """Copy `bag` without pier a's valve commands from `last_step` on, with pier b's final
    status moved after every other message (the order a recorder may hear them in)."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    held, end_ns = [], 0
    with Reader(bag) as reader, Writer(dst, version=9) as writer:
        conns = {c.topic: writer.add_connection(c.topic, c.msgtype, typestore=store)
                 for c in reader.connections}
        for conn, ns, raw in reader.messages():
            end_ns = max(end_ns, ns)
            msg = store.deserialize_cdr(raw, conn.msgtype)
            if (conn.topic == '/pier_a/seft/valve_command'
                    and msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                    >= last_step * 2_000_000):
                continue
            if conn.topic == '/seft/status' and msg.name == 'pier_b/rig' and any(
                    kv.key == 'state' and kv.value == 'aborted' for kv in msg.values):
                held.append((conns[conn.topic], raw))
                continue
            writer.write(conns[conn.topic], ns, raw)
        assert len(held) == 1
        writer.write(*held[0][:1], end_ns + 1, held[0][1])
    return dst


def test_a_rig_whose_specimen_disagrees_with_the_structure_is_refused(tmp_path):
    text = BRIDGE.format(builders='central', predictor='model', rig_b='servohydraulic')
    text = text.replace('stiffness_N_per_m: 3.376e5', 'stiffness_N_per_m: 3.0e5')
    with pytest.raises(parameters.ParameterError, match=(
            r"config.yaml: structure: the stiffness to the ground at physical dof 'pier_b' is "
            r"337600.0 N/m \(the row sum of the stiffness matrix\), but rig pier_b's specimen "
            r'has stiffness_N_per_m=300000.0: the structure disagrees with the specimen$')):
        _params(tmp_path, text)


def test_a_structure_that_is_the_study_runs_as_the_study(tmp_path):
    """One physical DOF carrying a rigid mass: alpha = mu / m, no structure, the rig's
    parameters (bit for bit the study's run)."""
    text = ('predictor: model\nstructure:\n  physical: {floor_1: lab}\n'
            '  story_masses_kg: [105.4]\n  story_stiffnesses_N_per_m: [2.11e5]\n'
            '  story_damping_N_s_per_m: [903.278]\nrigs:\n  lab: {rig_model: delay}\n')
    p = _params(tmp_path, text)
    assert p['structure'] == 'none' and p['alpha'] == 1.0 and p['rig_model'] == 'delay'
    assert p == parameters.resolve({'alpha': 1.0, 'predictor': 'model', 'rig_model': 'delay'})


def test_rigs_without_a_structure_is_one_error_line(tmp_path):
    from seft_msgs_py.errors import InputError
    path = Path(tmp_path / 'c.yaml')
    path.write_text('rigs:\n  lab: {rig_model: delay}\n')
    with pytest.raises(InputError, match=r'c.yaml: rigs: a rigs section needs a structure '
                                         r'section'):
        load_config(path)


def test_two_rigs_in_real_time_start_together_and_lose_nothing(runner, tmp_path):
    """Real time: each rig on its own timer, started at the instant the clock master
    announced; every step of both rigs is in the bag and no command was lost."""
    params = _params(tmp_path, BRIDGE.format(builders='central', predictor='model',
                                             rig_b='servohydraulic'))
    params = dict(params, mode='realtime', watchdog_timeout_s=0.2)
    out = runner.run(params, tmp_path / 'run')
    rd = read_run(out.bag_path)
    assert rd.n_steps == 500, rd.abort_reason
    timing = rd.extra['timing']
    assert timing['lost_commands'] == 0
    assert {'pier_a/rig', 'pier_b/rig', 'reference_force_builder'} <= set(timing['nodes'])
    starts = {s['name']: int(s['t0_ns']) for s in rd.extra['node_statuses']
              if s.get('state') == 'running' and 't0_ns' in s}
    assert set(starts) == {'pier_a/rig', 'pier_b/rig'}
    # the announced instant, 0.5 s after the master armed; each rig's sample 0 within a
    # few scheduling delays of it
    announced = [int(s['start_at_ns']) for s in rd.extra['node_statuses']
                 if 'start_at_ns' in s]
    assert len(announced) == 1
    for name, t0 in starts.items():
        assert 0 <= t0 - announced[0] < 20_000_000, name


def test_seft_run_and_compare_of_a_structure_config(seft_exe, run_process, tmp_path):
    """As a user runs it: seft run on a structure config prints one line per degree of
    freedom and writes the report; seft compare of the run folder gives the same summary."""
    config = tmp_path / 'two_story.yaml'
    config.write_text(TWO_STORY.replace('duration_s: 1.0', 'duration_s: 0.6'))
    out = tmp_path / 'run'
    proc = run_process([seft_exe, 'run', config, '--out', out], cwd=tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert any(re.match(r'\s+1\s+model\s+True\s+-\s+story_1\s+lab\s', ln) for ln in lines)
    assert any(re.match(r'\s+1\s+model\s+True\s+-\s+story_2\s+-\s', ln) for ln in lines)
    summary = json.loads((out / 'summary.json').read_text())['runs']
    assert summary[0]['structure']['physical'] == {'story_1': 'lab'}
    assert summary[0]['bag_lost_messages'] == 0         # the recorder's count, as for one rig
    assert (out / 'structure_model' / 'bag' / 'metadata.yaml').is_file()
    assert (out / 'report.html').is_file()
    again = tmp_path / 'compared'
    proc = run_process([seft_exe, 'compare', out, '--out', again], cwd=tmp_path, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert json.loads((again / 'summary.json').read_text())['runs'][0]['dofs'] == \
        summary[0]['dofs']


def test_labs_exchange_their_identified_piers_in_lockstep_as_simulate_does(runner, tmp_path,
                                                                           monkeypatch):
    """One builder per pier ('per_rig', each lab's), 'adaptive' with each pier's model 10 %
    stiff: the builders send their identified models every 50 steps and take the others' in
    25 steps later (/<rig>/seft/specimen_model; lockstep waits for them), so the bag equals
    seft simulate bit for bit, and the exchange changed the run (without it, simulate
    differs). Each rig's estimates are in the bag on /<rig>/seft/estimates."""
    from seft_ros.core import reference_force
    text = (BRIDGE.format(builders='per_rig', predictor='adaptive', rig_b='servohydraulic')
            .replace('duration_s: 1.0', 'duration_s: 2.5')
            .replace('pier_a: {force_controller: specimen_loop_shaping}',
                     'pier_a: {force_controller: specimen_loop_shaping, '
                     'predictor_stiffness_N_per_m: 232100.0}')
            .replace('rig_model: servohydraulic}',
                     'rig_model: servohydraulic, predictor_stiffness_N_per_m: 371360.0}'))
    params = _params(tmp_path, text)
    out = runner.run(params, tmp_path / 'run')
    assert out.rig_state in ('done', ''), out.message
    rd = read_run(out.bag_path)
    assert rd.stable
    sim = simulate(rd.params)
    _same_run(rd, sim)
    for rig in ('pier_a', 'pier_b'):
        k = rd.rigs[rig].estimates['stiffness_N_per_m']
        np.testing.assert_array_equal(k, sim.rigs[rig].estimates['stiffness_N_per_m'])
        assert k[-1] < 0.97 * k[0]                          # identified towards the truth
    monkeypatch.setattr(reference_force, 'EXCHANGE_EVERY_STEPS', 10 ** 9)
    alone = simulate(rd.params)
    assert not np.array_equal(alone.rigs['pier_a'].reference_force_N,
                              sim.rigs['pier_a'].reference_force_N)
