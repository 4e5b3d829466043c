"""seft_ros.opensees.part and .reference: the model stepped on measured motion, and OpenSees'
own analysis of the whole structure, against independent references."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from seft_msgs_py.interface import Measurement
from seft_plant_sim.specimen import LinearSpecimen
from seft_ros.analysis.reference import structure_reference
from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.ground_motion import prepared_record
from seft_ros.core.structure import test_setup
from seft_ros.core.substructure import StructureState, computational_part
from seft_ros.opensees.part import OpenSeesPart, dry_run
from seft_ros.opensees.reference import opensees_reference

ROOT = Path(__file__).resolve().parents[3]
DT = 0.002


def _nrms(test, ref) -> np.ndarray:
    test, ref = np.asarray(test), np.asarray(ref)
    return np.sqrt(np.mean((test - ref) ** 2, axis=0)) / np.sqrt(np.mean(ref ** 2, axis=0))


@pytest.fixture(scope='module')
def two_story():
    """The OpenSees two-story building's setup and 4 s of the default record."""
    params = expand_runs(dict(load_config(ROOT / 'config' / 'opensees' / 'two_story.yaml'),
                              predictor='model', duration_s=4.0))[0]
    return test_setup(params), prepared_record(params).acceleration_m_s2


def test_factory_gives_the_model(two_story):
    setup, _ = two_story
    assert isinstance(computational_part(setup.substructures, DT), OpenSeesPart)


def test_reference_is_the_exact_linear_response(two_story):
    """OpenSees' analysis of the whole two-story building equals the exact solution of its matrices
    (first-order hold, exact for the linear record) within 0.05 %."""
    setup, ag = two_story
    sub = setup.substructures
    ref = opensees_reference(sub, DT, ag)
    exact = structure_reference(sub.structure, [LinearSpecimen(52.7, 903.278, 2.11e5)], DT, ag)
    assert np.all(_nrms(ref.displacement_m, exact.displacement_m) < 5e-4)
    assert np.all(_nrms(ref.acceleration_m_s2, exact.acceleration_m_s2) < 2e-3)
    assert _nrms(ref.interface_force_N, exact.interface_force_N)[0] < 2e-3


def test_replay_of_the_exact_motion(two_story):
    """Driven by the exact story-1 motion, the model's story 2 and its interface force follow
    the exact response as the matrix path's exact step does (4 substeps: within 0.05 %)."""
    setup, ag = two_story
    sub = setup.substructures
    exact = structure_reference(sub.structure, [LinearSpecimen(52.7, 903.278, 2.11e5)], DT, ag)
    part, matrix = OpenSeesPart(sub, DT), StructureState(sub, DT)
    x2, forces, forces_matrix = [], [], []
    for k in range(ag.shape[0]):
        m = Measurement(k, k * DT, exact.displacement_m[k, 0], exact.velocity_m_s[k, 0],
                        exact.acceleration_m_s2[k, 0], 0.0)
        for p in (part, matrix):
            p.observe(0, m)
            p.set_ground(k, float(ag[k]))
        x, v, window = part.state_at(k)
        assert window == 0
        x2.append(x[1])
        forces.append(part.interface_forces(x, v, [0])[0])
        xm, vm, _ = matrix.state_at(k)
        forces_matrix.append(matrix.interface_forces(xm, vm, [0])[0])
    assert _nrms(x2, exact.displacement_m[:, 1]) < 5e-4
    assert _nrms(forces, forces_matrix) < 5e-4
    assert len(part.step_times_s) == ag.shape[0] - 1
    names = part.state_names
    assert names == ('story_2/displacement_m', 'story_2/velocity_m_s',
                     'story_2/acceleration_m_s2', 'opensees/step_time_s')


def _deferred(tmp_path, name: str, **overrides):
    """config/opensees/<name>.yaml with ``step: deferred``: its setup."""
    path = ROOT / 'config' / 'opensees' / f'{name}.yaml'
    section = yaml.safe_load(path.read_text())
    section['structure']['opensees'].update(step='deferred', model=str(path.with_suffix('.py')))
    section.update(overrides)
    config = tmp_path / f'{name}.yaml'
    config.write_text(yaml.safe_dump(section))
    return test_setup(expand_runs(load_config(config))[0])


@pytest.mark.parametrize('amplitude_m, tolerance', [(1e-3, 1e-6), (0.02, 2e-3)])
def test_a_deferred_step_is_the_models_own_step(tmp_path, amplitude_m, tolerance):
    """``step: deferred``: the state the builder gets for sample k (the part's linear step from
    OpenSees' state of k-1) against OpenSees' own step to k, done after it (``advance``), on
    the steel frame with its floor 1 moving as a 2 Hz sine and a 3.1 Hz ground: elastic (1 mm)
    within 1e-6 of each signal's peak (measured 1e-9 x, 5e-7 a, 1.4e-7 force), yielding (20
    mm, its tangent read) within 2e-3 (measured 7e-7 x, 7e-4 a, 6e-4 force); the recorded
    state is OpenSees' own, one sample late."""
    setup = _deferred(tmp_path, 'steel_frame')
    part = OpenSeesPart(setup.substructures, DT)
    assert part.recorded_lag_steps == 1
    w = 2 * np.pi * 2.0
    ahead, own, recorded = [], [], []
    for k in range(600):
        t = k * DT
        part.observe(0, Measurement(k, t, amplitude_m * np.sin(w * t),
                                    amplitude_m * w * np.cos(w * t),
                                    -amplitude_m * w * w * np.sin(w * t), 0.0))
        part.set_ground(k, 0.5 * np.sin(2 * np.pi * 3.1 * t))
        x, v, _ = part.state_at(k)
        if k > 1:
            recorded.append(part.recorded_state(x, v, k)[:2])   # floor 2's x, floor 3's x
        ahead.append(x + [part.interface_forces(x, v, [0])[0]])
        part.advance()
        own.append(list(part._x) + [part._forces[0]])
    ahead, own = np.array(ahead[1:]), np.array(own[1:])
    peak = np.max(np.abs(own), axis=0)
    assert np.all(np.max(np.abs(ahead - own), axis=0) <= tolerance * peak), (
        np.max(np.abs(ahead - own), axis=0) / peak)
    np.testing.assert_array_equal(np.array(recorded), own[:-1, 1:3])
    if amplitude_m > 0.01:
        assert part.tangent_steps > 10                  # it yields


def test_nonlinear_frame_replay():
    """The yielding frame stepped on the reference's own floor-1 motion: its other floors
    follow OpenSees' analysis of the whole frame within 0.5 %, and its first-story column
    yields in both (moment beyond the first-yield moment of its S690 section)."""
    params = expand_runs(dict(load_config(ROOT / 'config' / 'opensees' / 'steel_frame.yaml'),
                              amplitude_N=2200.0, duration_s=2.5))[0]
    sub = test_setup(params).substructures
    ag = prepared_record(params).acceleration_m_s2
    ref = opensees_reference(sub, DT, ag, substeps=10)
    part = OpenSeesPart(sub, DT)
    x, moments = [], []
    index = part.state_names.index('opensees/ele111/force')
    for k in range(ag.shape[0]):
        part.observe(0, Measurement(k, k * DT, ref.displacement_m[k, 0], ref.velocity_m_s[k, 0],
                                    ref.acceleration_m_s2[k, 0], 0.0))
        part.set_ground(k, float(ag[k]))
        xs, vs, _ = part.state_at(k)
        x.append(xs)
        moments.append(part.recorded_state(xs, vs, k)[index])
    my = 690e6 * 0.012 * 0.040 ** 2 / 6.0           # first yield of the 40 x 12 mm column
    assert np.max(np.abs(ref.element_forces[111])) > 1.1 * my
    assert np.max(np.abs(moments)) > 1.1 * my
    assert np.all(_nrms(np.array(x)[:, 1:], ref.displacement_m[:, 1:]) < 5e-3)


def test_dry_run_times_each_step(two_story):
    setup, _ = two_story
    r = dry_run(setup.substructures, DT, steps=50)
    assert r.step_times_s.shape == (50,)
    assert 0.0 < r.p50_s <= r.p99_s <= r.max_s


#: config/opensees/shear_frame.py with Rayleigh damping on every story (``-doRayleigh``):
#: ``kind`` names the stiffness it is proportional to, ``some`` gives it to story 2 only.
RAYLEIGH_FRAME = """
import openseespy.opensees as ops

def build(fy2_N=3800.0, b=0.02, kind='initial', beta=0.002, some=False):
    ops.wipe()
    ops.model('basic', '-ndm', 2, '-ndf', 2)
    ops.node(0, 0.0, 0.0)
    ops.fix(0, 1, 1)
    for i, c in enumerate((903.278, 333.5, 333.5), start=1):
        ops.node(i, 0.0, 0.0)
        ops.fix(i, 0, 1)
        ops.mass(i, 52.7, 0.0)
        if i == 2:
            ops.uniaxialMaterial('Steel01', 10 + i, fy2_N, 2.11e5, b)
        else:
            ops.uniaxialMaterial('Elastic', 10 + i, 2.11e5)
        ops.uniaxialMaterial('Viscous', 20 + i, c, 1.0)
        ops.uniaxialMaterial('Parallel', 30 + i, 10 + i, 20 + i)
        ops.element('zeroLength', i, i - 1, i, '-mat', 30 + i, '-dir', 1,
                    '-doRayleigh', int(i == 2 or not some))
    factors = {'current': (beta, 0.0, 0.0), 'initial': (0.0, beta, 0.0),
               'committed': (0.0, 0.0, beta)}[kind]
    ops.rayleigh(0.0, *factors)
"""


def _yielding_frame(tmp_path, **arguments):
    """The shear frame's setup with story 2 yielding (RAYLEIGH_FRAME's `arguments`)."""
    if arguments:
        (tmp_path / 'frame.py').write_text(RAYLEIGH_FRAME)
        doc = yaml.safe_load((ROOT / 'config' / 'opensees' / 'shear_frame.yaml').read_text())
        doc['structure']['opensees'].update(model='frame.py',
                                            arguments=dict(arguments, fy2_N=3800.0))
        path = tmp_path / 'frame.yaml'
        path.write_text(yaml.safe_dump(doc))
    else:
        path = ROOT / 'config' / 'opensees' / 'shear_frame.yaml'
    params = expand_runs(dict(load_config(path), duration_s=1.0))[0]
    return test_setup(params).substructures


@pytest.mark.parametrize('arguments', [{}, {'kind': 'current'}, {'kind': 'committed'}],
                         ids=['no rayleigh', 'rayleigh current', 'rayleigh committed'])
def test_tangent_is_the_models_own(tmp_path, arguments):
    """The yielding story of config/opensees/shear_frame.yaml shaken (floor 1 held, 5 Hz
    ground motion): while it is elastic the part has no tangent (its linearization holds);
    while it yields its tangent is the bilinear story's, ``b k`` in place of ``k`` in the
    computational stiffness, from OpenSees' assembled system (within 1e-6); when it unloads,
    none again. The same with Rayleigh damping on every story's current or committed
    stiffness, which Newton's system holds beside the tangent (before, the tangent was read
    as ``K_t + (2/h) beta (K_t - K_0)``: -2.1e5 N/m in place of 4.2e3 with beta 0.002 at 1
    ms, and the test lost force control); with the committed stiffness, a step that changed
    the tangent reads a mean of the two tangents (the new one committed at the next step,
    read then)."""
    from seft_ros.opensees.loader import rayleigh_calls
    sub = _yielding_frame(tmp_path, **arguments)
    part = OpenSeesPart(sub, DT)
    part.prepare()
    if arguments:
        assert rayleigh_calls()[-1][0] == 'rayleigh'
    k, b = 2.11e5, 0.02
    fy = float(part.spec.arguments['fy2_N'])
    k_c = sub.stiffness_c_N_per_m
    np.testing.assert_allclose(k_c, [[k, -k, 0], [-k, 2 * k, -k], [0, -k, k]], rtol=1e-12)
    yielded = k_c + (b - 1.0) * k * np.array([[1, -1, 0], [-1, 1, 0], [0, 0, 0]])
    seen = {'elastic': 0, 'yielding': 0, 'unloading': 0, 'between': 0}
    drift_before = 0.0
    for j in range(300):
        part.observe(0, Measurement(j, j * DT, 0.0, 0.0, 0.0, 0.0))
        part.set_ground(j, 40.0 * np.sin(2 * np.pi * 5.0 * j * DT) * min(1.0, j / 150))
        x = part.state_at(j)[0]
        tangent = part.tangent()
        drift = x[1] - x[0]
        if abs(drift) < 0.9 * fy / k and seen['yielding'] == 0:
            assert tangent is None, j                  # before the first yield
            seen['elastic'] += 1
        elif tangent is not None and np.max(np.abs(tangent - yielded)) < 1e-6 * k:
            seen['yielding'] += 1
        elif tangent is not None:
            # the committed stiffness only: a mean of the yielded and the initial tangent
            assert arguments.get('kind') == 'committed', (j, tangent)
            low, high = np.minimum(k_c, yielded), np.maximum(k_c, yielded)
            assert np.all((tangent >= low - 1e-6 * k) & (tangent <= high + 1e-6 * k)), tangent
            seen['between'] += 1
        elif seen['yielding'] and abs(drift) < abs(drift_before):
            seen['unloading'] += 1                     # back on the linearization
        drift_before = drift
    assert seen['elastic'] > 20 and seen['yielding'] > 10 and seen['unloading'] > 10, seen
    assert seen['between'] <= 4, seen                  # one per yielding episode at most
    if not arguments:       # read where the tangent changed (with this damping Newton
        # takes a second iteration on every step, and the tangent is read on each)
        assert 2 <= part.tangent_steps < seen['yielding'], part.tangent_steps


def test_deficit_forces_are_the_yielding_storys_own(tmp_path):
    """The restoring forces' deficit the part gives (``K_c,0 x - R(x)``, from its equation of
    motion) is story 2's alone: ``(k delta - f_s) (-1, 1, 0)``, ``f_s`` its Steel01 spring's
    force (the element's force less its dashpot's, ``c (v2 - v1)``), at every sample of the
    same shaking as above, elastic and yielding, to 1e-9 of the largest (measured 7.5e-11 N
    of 11 kN)."""
    from seft_ros.opensees.loader import opensees
    sub = _yielding_frame(tmp_path)
    part = OpenSeesPart(sub, DT)
    part.prepare()
    ops = opensees()
    k, c = 2.11e5, 333.5                                   # story 2 (shear_frame.py)
    errors, largest = [], 0.0
    for j in range(300):
        part.observe(0, Measurement(j, j * DT, 0.0, 0.0, 0.0, 0.0))
        part.set_ground(j, 40.0 * np.sin(2 * np.pi * 5.0 * j * DT) * min(1.0, j / 150))
        x, v, _ = part.state_at(j)
        spring = float(ops.eleForce(2, 3)) - c * (v[1] - v[0])
        closed = (k * (x[1] - x[0]) - spring) * np.array([-1.0, 1.0, 0.0])
        errors.append(np.max(np.abs(part.deficit_forces(x, v) - closed)))
        largest = max(largest, float(np.max(np.abs(closed))))
    assert largest > 5e3                                   # it yielded well past its onset
    assert max(errors) < 1e-9 * largest, (max(errors), largest)


def test_rayleigh_damping_on_the_current_stiffness_of_some_elements_is_refused(tmp_path):
    """Damping on the current stiffness that story 2 takes and story 3 does not (a
    ``zeroLength`` without ``-doRayleigh``): the tangent cannot be told from Newton's system;
    one line says so and what to do."""
    from seft_ros.opensees.model import ModelError
    part = OpenSeesPart(_yielding_frame(tmp_path, kind='current', some=True), DT)
    with pytest.raises(ModelError, match=r'^structure\.opensees\.model: Rayleigh damping on the '
                       r'current or committed stiffness \(ops\.rayleigh\(0, 0\.002, 0, 0\)\) '
                       r'that some elements take and others not .*; give it to every element, '
                       r'put it on the initial stiffness \(beta_K_init\), or set prediction: '
                       r'initial$'):
        part.prepare()


#: A two-story building whose build() runs a static analysis of 100 N at node ``at`` (2: its
#: roof, a lateral load; 3: a massless node on its own spring to the ground, a load that
#: displaces no DOF of the building), held by loadConst (``held``) or left on its linear
#: series.
LOADED_BUILDING = """
import openseespy.opensees as ops

def build(held=True, at=3):
    ops.wipe()
    ops.model('basic', '-ndm', 1, '-ndf', 1)
    ops.node(0, 0.0)
    ops.fix(0, 1)
    for i in (1, 2):
        ops.node(i, 0.0)
        ops.mass(i, 52.7)
        ops.uniaxialMaterial('Elastic', i, 2.11e5, 903.278 if i == 1 else 333.5)
        ops.element('zeroLength', i, i - 1, i, '-mat', i, '-dir', 1)
    ops.node(3, 0.0)
    ops.uniaxialMaterial('Elastic', 3, 1e5)
    ops.element('zeroLength', 3, 0, 3, '-mat', 3, '-dir', 1)
    ops.timeSeries('Linear', 1)
    ops.pattern('Plain', 1, 1)
    ops.load(at, 100.0)
    ops.constraints('Plain')
    ops.numberer('Plain')
    ops.system('BandGeneral')
    ops.test('NormDispIncr', 1e-8, 10)
    ops.algorithm('Newton')
    ops.integrator('LoadControl', 0.1)
    ops.analysis('Static')
    ops.analyze(10)
    if held:
        ops.loadConst('-time', 0.0)
"""


def _loaded_part(tmp_path, held, at):
    (tmp_path / 'loaded.py').write_text(LOADED_BUILDING)
    doc = {'structure': {'opensees': {'model': 'loaded.py',
                                      'arguments': {'held': held, 'at': at},
                                      'dofs': {'s1': [1, 1], 's2': [2, 1]},
                                      'physical_elements': {'lab': [1]}},
                         'physical': {'s1': 'lab'}},
           'rigs': {'lab': {'rig_model': 'delay'}}, 'predictor': 'none', 'duration_s': 0.1}
    (tmp_path / 'loaded.yaml').write_text(yaml.safe_dump(doc))
    params = expand_runs(load_config(tmp_path / 'loaded.yaml'))[0]
    return OpenSeesPart(test_setup(params).substructures, DT)


def _three_steps(part):
    for j in range(3):
        part.observe(0, Measurement(j, j * DT, 0.0, 0.0, 0.0, 0.0))
        part.set_ground(j, 0.0)
        part.state_at(j)


@pytest.mark.parametrize('held', [True, False])
def test_a_load_left_on_its_time_series_is_refused_at_the_first_step(tmp_path, held):
    """A static analysis in build() (its load beside the building: none of its DOFs
    displaced): held by loadConst the pattern stays (its factor 1 at every step); left on its
    linear series its load would grow with the test's time (the test 8-26 % off its
    reference, silently, before): refused at the first step."""
    from seft_ros.opensees.model import ModelError
    part = _loaded_part(tmp_path, held, at=3)
    part.prepare()
    if held:
        _three_steps(part)
        return
    with pytest.raises(ModelError, match=r'^structure\.opensees\.model: its load pattern 1 is '
                       r'not constant \(its factor moved from 1 to 1\.00[12] over the first '
                       r'step: .*call ops\.loadConst\(\'-time\', 0\.0\) after the analysis, or '
                       r'remove the pattern$'):
        _three_steps(part)


def test_a_lateral_load_held_through_the_interface_is_refused_at_rest(tmp_path):
    """100 N at the roof held by loadConst holds the specimen's DOF at 100 / 2.11e5 m =
    0.4739 mm where the rig starts at 0 (a start-up transient of 7 % over 1 s before):
    refused before the first step, in one line with the displacement."""
    from seft_ros.opensees.model import ModelError
    part = _loaded_part(tmp_path, True, at=2)
    with pytest.raises(ModelError, match=r'^structure\.opensees\.model: its own loads hold the '
                       r'interface DOF s1 \(node 1, dof 1\) at 0\.4739 mm at the start, where '
                       r"the rig's specimen starts unloaded at 0 .*; leave lateral loads out of "
                       r'build\(\) \(gravity on a frame that does not sway may stay\)$'):
        part.prepare()
