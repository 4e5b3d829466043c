"""seft_ros.opensees.model: a structure from an OpenSeesPy model, its checks and its
linearization (against the matrix form of the same structure, an independent path)."""

import os
from pathlib import Path
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from seft_msgs_py.errors import ParameterError
from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.structure import Structure, parse_structure, test_setup
from seft_ros.opensees.checks import check_runs
from seft_ros.opensees.model import ModelError

ROOT = Path(__file__).resolve().parents[3]
TWO_STORY = ROOT / 'config' / 'opensees' / 'two_story.py'


def _section(**opensees):
    body = {'model': str(TWO_STORY), 'dofs': {'story_1': [1, 1], 'story_2': [2, 1]},
            'physical_elements': {'lab': [1]}}
    body.update(opensees)
    return {'opensees': body, 'physical': {'story_1': 'lab'}}


def _model(tmp_path, text: str) -> str:
    path = tmp_path / 'model.py'
    path.write_text(textwrap.dedent(text))
    return str(path)


def test_loads_in_a_fresh_process_without_the_library_path():
    """The wheel's libblas is loaded inside seft: no LD_LIBRARY_PATH needed. The process
    ends with its own last line: OpenSees' 'Process 0 Terminating' at the exit is not
    written (it followed every OpenSees command's output, session 35)."""
    env = {k: v for k, v in os.environ.items() if k != 'LD_LIBRARY_PATH'}
    code = ("import atexit, sys; atexit.register(lambda: print('an exit hook', file=sys.stderr))"
             '; from seft_ros.opensees.loader import opensees; ops = opensees(); ops.wipe(); '
            "ops.model('basic', '-ndm', 1, '-ndf', 1); ops.node(1, 0.0); print(ops.getNodeTags())"
            "; print('last line', file=sys.stderr)")
    out = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert '[1]' in out.stdout
    # what Python writes after the hook still reaches the standard error (an earlier
    # hook's line; the session's review: the first hook lost it)
    assert out.stderr == 'last line\nan exit hook\n'


def test_two_story_model_is_the_matrix_structure():
    """The OpenSees two-story building linearizes to config/two_story.yaml's matrices and
    splits into the same specimen and computational part."""
    model = load_config(ROOT / 'config' / 'opensees' / 'two_story.yaml')
    matrix = load_config(ROOT / 'config' / 'two_story.yaml')
    a = test_setup(expand_runs(dict(model, predictor='model'))[0])
    b = test_setup(expand_runs(dict(matrix, predictor='model'))[0])
    sa, sb = a.substructures, b.substructures
    for name in ('mass_kg', 'damping_N_s_per_m', 'stiffness_N_per_m'):
        np.testing.assert_allclose(getattr(sa.structure, name), getattr(sb.structure, name),
                                   rtol=1e-12, atol=1e-9)
    for name in ('mass_c_kg', 'damping_c_N_s_per_m', 'stiffness_c_N_per_m',
                 'specimen_mass_kg', 'specimen_damping_N_s_per_m',
                 'specimen_stiffness_N_per_m', 'alpha'):
        np.testing.assert_allclose(getattr(sa, name), getattr(sb, name), rtol=1e-12, atol=1e-9)
    assert sa.structure.dofs == ('story_1', 'story_2')
    assert [lk.name for lk in sa.structure.links] == ['story_1-ground', 'story_2-story_1']
    # the JSON round trip keeps the model
    again = Structure.from_json(sa.structure.to_json())
    assert again.model['physical_elements'] == {'lab': [1]}


def test_a_script_without_a_function(tmp_path):
    """A model file that builds the model as a script (function: null), its arguments as
    globals: the same structure as the two-story function."""
    path = _model(tmp_path, """
        import openseespy.opensees as ops
        ops.wipe(); ops.model('basic', '-ndm', 1, '-ndf', 1)
        ops.node(0, 0.0); ops.fix(0, 1)
        for i, c in ((1, 903.278), (2, 333.5)):
            ops.node(i, 0.0); ops.mass(i, 52.7)
            ops.uniaxialMaterial('Elastic', i, k, c)
            ops.element('zeroLength', i, i - 1, i, '-mat', i, '-dir', 1)
    """)
    script = parse_structure(_section(model=path, function=None, arguments={'k': 2.11e5}))
    function = parse_structure(_section())
    np.testing.assert_allclose(script.stiffness_N_per_m, function.stiffness_N_per_m)
    np.testing.assert_allclose(script.damping_N_s_per_m, function.damping_N_s_per_m)
    assert script.model['function'] == ''


def test_frame_is_condensed_to_its_floors():
    """The steel frame's 24 equations condense to its three floors (Guyan): the condensed
    stiffness gives the model's own static floor displacements under a lateral load."""
    from seft_ros.opensees.loader import opensees
    s = load_config(ROOT / 'config' / 'opensees' / 'steel_frame.yaml')
    structure = Structure.from_json(s['structure'])
    assert structure.dofs == ('floor_1', 'floor_2', 'floor_3')
    np.testing.assert_allclose(np.diag(structure.mass_kg), [80.0, 70.0, 60.0])
    # OpenSees' own static analysis of the whole frame under 1 kN at floor 3
    ops = opensees()
    import importlib.util
    spec = importlib.util.spec_from_file_location('frame_for_test',
                                                  ROOT / 'config' / 'opensees' / 'steel_frame.py')
    frame = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(frame)
    frame.build()
    ops.wipeAnalysis()
    ops.timeSeries('Linear', 1)
    ops.pattern('Plain', 1, 1)
    ops.load(31, 1000.0, 0.0, 0.0)
    ops.constraints('Transformation')
    ops.numberer('RCM')
    ops.system('BandGeneral')
    ops.algorithm('Linear')
    ops.integrator('LoadControl', 1.0)
    ops.analysis('Static')
    assert ops.analyze(1) == 0
    x = [ops.nodeDisp(n, 1) for n in (11, 21, 31)]
    expected = np.linalg.solve(structure.stiffness_N_per_m, [0.0, 0.0, 1000.0])
    np.testing.assert_allclose(x, expected, rtol=1e-6)


@pytest.mark.parametrize('change, match', [
    ({'dofs': {'story_1': [1, 1], 'story_2': [7, 1]}},
     r'structure\.opensees\.dofs\.story_2: node 7 is not in the model \(3 nodes: 0, 1, 2\)'),
    ({'dofs': {'story_1': [1, 1], 'story_2': [2, 3]}},
     r'structure\.opensees\.dofs\.story_2: node 2 has 1 dofs \(1\.\.1\), no dof 3'),
    ({'physical_elements': {'lab': [5]}},
     r'physical_elements\.lab: element 5 is not in the model'),
    # a rig no dof names: the physical key named, not the file pasted mid-sentence (a new
    # user, session 36)
    ({'physical_elements': {'lab': [1], 'lab2': [1]}},
     r'^structure\.opensees\.physical_elements\.lab2: no dof of structure\.physical names '
     r'this rig \(rigs: lab\)$'),
    ({'substeps': 0}, r'structure\.opensees\.substeps: expected an integer >= 1, got 0'),
    ({'colour': 'red'}, r'structure\.opensees\.colour: unknown key'),
    ({'step': 'later'},
     r"structure\.opensees\.step: expected one of immediate, deferred, got 'later'"),
    ({'pushover': 'no'}, r"structure\.opensees\.pushover: expected true or false, got 'no'"),
    ({'model': 'nowhere.py'}, r'structure\.opensees\.model: .*nowhere\.py: no such model file'),
    ({'function': 'construct'},
     r"structure\.opensees\.function: two_story\.py has no function 'construct'"),
])
def test_bad_sections_are_one_line(change, match):
    with pytest.raises(ParameterError, match=match) as info:
        parse_structure(_section(**change))
    assert '\n' not in str(info.value)


def test_element_not_connected_to_its_interface(tmp_path):
    """A specimen element away from its rig's interface node is named."""
    path = _model(tmp_path, """
        import openseespy.opensees as ops
        def build():
            ops.wipe(); ops.model('basic', '-ndm', 1, '-ndf', 1)
            for n in range(4):
                ops.node(n, 0.0)
            ops.fix(0, 1); ops.fix(3, 1)
            ops.mass(1, 60.0); ops.mass(2, 50.0)
            ops.uniaxialMaterial('Elastic', 1, 2.11e5, 903.278)
            ops.element('zeroLength', 1, 0, 1, '-mat', 1, '-dir', 1)
            ops.element('zeroLength', 2, 1, 2, '-mat', 1, '-dir', 1)
            ops.element('zeroLength', 3, 2, 3, '-mat', 1, '-dir', 1)
    """)
    with pytest.raises(ParameterError, match=r'physical_elements\.lab: element 3 \(nodes 2, 3\) '
                       r'is not connected to the interface node 1 of rig lab'):
        parse_structure(_section(model=path, physical_elements={'lab': [3]}))


def test_interface_on_the_constrained_side(tmp_path):
    """The rig must test the retained node of an equalDOF, not the node tied to it."""
    path = _model(tmp_path, """
        import openseespy.opensees as ops
        def build():
            ops.wipe(); ops.model('basic', '-ndm', 1, '-ndf', 1)
            for n in range(4):
                ops.node(n, 0.0)
            ops.fix(0, 1)
            ops.mass(1, 60.0); ops.mass(2, 50.0)
            ops.uniaxialMaterial('Elastic', 1, 2.11e5, 903.278)
            ops.element('zeroLength', 1, 0, 1, '-mat', 1, '-dir', 1)
            ops.element('zeroLength', 2, 1, 2, '-mat', 1, '-dir', 1)
            ops.equalDOF(3, 1, 1)
    """)
    with pytest.raises(ParameterError, match=r'rig lab tests node 1 dof 1, which a multi-point '
                       r'constraint ties to node 3: name the retained node'):
        parse_structure(_section(model=path))


def test_a_model_that_fails_keeps_opensees_message(tmp_path):
    path = _model(tmp_path, """
        import openseespy.opensees as ops
        def build():
            ops.wipe(); ops.model('basic', '-ndm', 1, '-ndf', 1)
            ops.node(0, 0.0); ops.node(1, 0.0)
            ops.element('zeroLength', 1, 0, 1, '-mat', 42, '-dir', 1)
    """)
    with pytest.raises(ModelError, match=r'structure\.opensees\.model: model\.py: build\(\) '
                       r'failed: OpenSees: .*(tag: 42|material 42)'):
        parse_structure(_section(model=path))


def test_the_fault_is_quoted_not_a_warning_before_it(tmp_path):
    """A harmless warning before the fault (a zeroLength element 3 m long) was quoted in
    place of the fault (a new user's material typo; session 38)."""
    path = _model(tmp_path, """
        import openseespy.opensees as ops
        def build():
            ops.wipe(); ops.model('basic', '-ndm', 2, '-ndf', 2)
            ops.node(0, 0.0, 0.0); ops.node(1, 0.0, 3.0)
            ops.uniaxialMaterial('Elastic', 1, 1.0e5)
            ops.element('zeroLength', 1, 0, 1, '-mat', 1, '-dir', 1)
            ops.uniaxialMaterial('Steel1', 2, 1.0e3, 1.0e5, 0.02)
    """)
    with pytest.raises(ModelError, match=r'failed: OpenSees: WARNING material type Steel1 is '
                       r'unknown$'):
        parse_structure(_section(model=path))


def test_a_model_that_raises_is_named(tmp_path):
    path = _model(tmp_path, """
        def build():
            raise ValueError('no such section W14x90')
    """)
    with pytest.raises(ModelError, match=r'model\.py: build\(\) failed: ValueError: no such '
                       'section W14x90'):
        parse_structure(_section(model=path))


def test_rig_that_disagrees_with_its_elements():
    with pytest.raises(ParameterError, match=r"physical_elements\.lab: the specimen's elements "
                       r'give node 1 dof 1 a stiffness of 211000 N/m, but rig lab\'s '
                       r'stiffness_N_per_m=250000'):
        s = parse_structure(_section(), rigs={'lab': {'stiffness_N_per_m': 2.5e5}})
        params = dict(expand_runs({'predictor': 'none'})[0], structure=s.to_json())
        test_setup(params)


def test_a_specimen_on_a_node_tied_to_the_interface_is_told_where_to_go(tmp_path):
    """A 2-D floor of two nodes tied by equalDOF (retained 12, constrained 11), the brace on
    11: refused, and the message says the tie and the node to connect it to (before: only
    'not connected')."""
    path = _model(tmp_path, """
        import openseespy.opensees as ops
        def build():
            ops.wipe(); ops.model('basic', '-ndm', 2, '-ndf', 2)
            ops.node(1, 0.0, 0.0); ops.node(2, 1.0, 0.0)
            ops.node(11, 0.0, 1.0); ops.node(12, 1.0, 1.0); ops.node(90, -1.0, 1.0)
            ops.fix(1, 1, 1); ops.fix(2, 1, 1); ops.fix(90, 1, 1)
            ops.fix(11, 0, 1); ops.fix(12, 0, 1)
            ops.mass(12, 100.0, 0.0)
            ops.uniaxialMaterial('Elastic', 1, 2.11e5, 903.278)
            ops.element('zeroLength', 1, 1, 11, '-mat', 1, '-dir', 1)
            ops.element('zeroLength', 2, 2, 12, '-mat', 1, '-dir', 1)
            ops.equalDOF(12, 11, 1)
            ops.element('zeroLength', 9, 90, 11, '-mat', 1, '-dir', 1)
    """)
    with pytest.raises(ParameterError, match=r'physical_elements\.lab: element 9 \(nodes 90, '
                       r'11\) is not connected to the interface node 12 of rig lab; its node 11 '
                       r'is tied to node 12 by an equalDOF: connect the element to node 12 '
                       r'itself \(the rig acts there\)$'):
        parse_structure({'opensees': {'model': path, 'dofs': {'floor': [12, 1]},
                                      'physical_elements': {'lab': [9]}},
                         'physical': {'floor': 'lab'}})


def test_a_story_as_the_specimen_names_the_dof_it_also_acts_on():
    """Story 2's spring as the specimen of the rig at story 2 acts on story 1 too: the
    largest term is story 1's own stiffness, named as such (before: 'between story_1 and
    story_1')."""
    s = parse_structure({'opensees': {'model': str(TWO_STORY),
                                      'dofs': {'story_1': [1, 1], 'story_2': [2, 1]},
                                      'physical_elements': {'lab': [2]}},
                         'physical': {'story_2': 'lab'}})
    params = dict(expand_runs({'predictor': 'none'})[0], structure=s.to_json())
    with pytest.raises(ParameterError, match=r"the specimens act on other dofs than their rigs' "
                       r'\(stiffness [\d.e+]+ N/m at story_1, which no rig tests\): a rig '
                       'drives one dof'):
        test_setup(params)


def test_specimen_acting_on_other_dofs():
    """Story 2's spring as the specimen of the rig at story 1 also acts on story 2."""
    s = parse_structure(_section(physical_elements={'lab': [2]}))
    params = dict(expand_runs({'predictor': 'none'})[0], structure=s.to_json())
    with pytest.raises(ParameterError, match=r"the specimens act on other dofs than their rigs' "
                       r'\(stiffness -211000 N/m between story_1 and story_2\): a rig drives one '
                       'dof'):
        test_setup(params)


def test_runs_that_cannot_run_are_refused(tmp_path):
    """A builder per rig, and a real-time run whose model does not fit the period."""
    s = parse_structure(_section(substeps=400))
    base = dict(expand_runs({'predictor': 'model'})[0], structure=s.to_json())
    check_runs([dict(base, structure_builders='per_rig')], progress=lambda _: None)  # one rig
    piers = _model(tmp_path, """
        import openseespy.opensees as ops
        def build():
            ops.wipe(); ops.model('basic', '-ndm', 1, '-ndf', 1)
            for n in range(3):
                ops.node(n, 0.0)
            ops.fix(0, 1)
            ops.mass(1, 60.0); ops.mass(2, 60.0)
            ops.uniaxialMaterial('Elastic', 1, 2.11e5, 903.278)
            ops.element('zeroLength', 1, 0, 1, '-mat', 1, '-dir', 1)
            ops.element('zeroLength', 2, 0, 2, '-mat', 1, '-dir', 1)
            ops.element('zeroLength', 3, 1, 2, '-mat', 1, '-dir', 1)
    """)
    two = parse_structure({'opensees': {
        'model': piers, 'dofs': {'pier_a': [1, 1], 'pier_b': [2, 1]},
        'physical_elements': {'a': [1], 'b': [2]}}, 'physical': {'pier_a': 'a', 'pier_b': 'b'}})
    with pytest.raises(ParameterError, match=r"structure_builders='per_rig': the OpenSees model "
                       r'model\.py:build is stepped .* not as a replica per rig \(2 rigs\)'):
        check_runs([dict(base, structure=two.to_json(), structure_builders='per_rig')],
                   progress=lambda _: None)
    lines = []
    with pytest.raises(ParameterError, match=r'structure\.opensees: two_story\.py:build: a '
                       r'timed dry run took [0-9.]+ ms per step \(median\), more than 0\.5 of '
                       r'the sample period dt = 2 ms'):
        check_runs([dict(base, mode='realtime')], progress=lines.append)
    assert lines and lines[0].startswith('opensees: two_story.py:build: a dry run of 500 steps')
    check_runs([dict(base, structure=parse_structure(_section()).to_json(),
                     mode='realtime')], progress=lines.append)


#: A 2-D cantilever (ndf 3) with its floor's mass horizontal only, the specimen a horizontal
#: spring from a fixed node: no mass in dof 2 (vertical) or 3 (the rotation).
CANTILEVER_2D = """
    import openseespy.opensees as ops
    def build():
        ops.wipe(); ops.model('basic', '-ndm', 2, '-ndf', 3)
        ops.node(0, 0.0, 0.0); ops.fix(0, 1, 1, 1)
        ops.node(1, 0.0, 1.0); ops.mass(1, 52.7, 0.0, 0.0)
        ops.geomTransf('Linear', 1)
        ops.element('elasticBeamColumn', 2, 0, 1, 4.8e-4, 200e9, 6.4e-8, 1)
        ops.node(9, 0.0, 1.0); ops.fix(9, 1, 1, 1)
        ops.uniaxialMaterial('Elastic', 1, 2.11e5, 903.278)
        ops.element('zeroLength', 1, 9, 1, '-mat', 1, '-dir', 1)
"""


@pytest.mark.parametrize('model, excitation, ndf', [
    (None, 2, 1),                   # the 1-D two-story building
    (CANTILEVER_2D, 2, 3), (CANTILEVER_2D, 3, 3), (CANTILEVER_2D, 7, 3)])
def test_an_excitation_dof_without_mass_is_refused(tmp_path, model, excitation, ndf):
    """An excitation direction in which no DOF has mass would excite nothing (a run of a
    structure that never moves, reported stable): refused, naming the directions with mass.
    The rotation of a 2-D frame (dof 3) was refused as 'the elements carry mass'."""
    change = {'excitation_dof': excitation}
    if model is not None:
        change.update(model=_model(tmp_path, model), dofs={'top': [1, 1]})
    section = _section(**change)
    if model is not None:
        section['physical'] = {'top': 'lab'}
    with pytest.raises(ParameterError) as info:
        parse_structure(section)
    assert str(info.value) == (
        f'structure.opensees.excitation_dof: {excitation}: no DOF with mass in that direction '
        f'(the model has ndf {ndf}; masses in dof 1)')


def test_the_excitation_dof_with_mass_is_taken(tmp_path):
    """The same 2-D cantilever excited along its floor's mass: one DOF, excited."""
    s = parse_structure({'opensees': {'model': _model(tmp_path, CANTILEVER_2D),
                                      'dofs': {'top': [1, 1]}, 'physical_elements': {'lab': [1]},
                                      'excitation_dof': 1}, 'physical': {'top': 'lab'}})
    assert s.dofs == ('top',)
    np.testing.assert_allclose(s.influence, [1.0])


@pytest.mark.parametrize('text, function, message', [
    ('import sys\ndef build():\n    sys.exit(3)\n', 'build',
     'structure.opensees.model: model.py: build() failed: SystemExit: 3'),
    ('import sys\nprint("built")\nsys.exit(0)\n', None,
     'structure.opensees.model: model.py failed: SystemExit: 0'),
    ('import sys\nsys.exit("no licence")\ndef build():\n    pass\n', 'build',
     'structure.opensees.model: model.py: importing it raised SystemExit: no licence'),
])
def test_a_model_that_calls_sys_exit_is_refused(tmp_path, text, function, message):
    """sys.exit() in a model (its function, a script, or at import) is the model's failure,
    not seft's exit: before, seft ended silently with the model's status (0 looked like
    success)."""
    path = tmp_path / 'model.py'
    path.write_text(text)
    with pytest.raises(ModelError) as info:
        parse_structure(_section(model=str(path), function=function))
    assert str(info.value) == message


def test_a_model_interrupted_by_ctrl_c_still_interrupts(tmp_path):
    """Only SystemExit is the model's failure: a KeyboardInterrupt stops seft."""
    path = _model(tmp_path, """
        def build():
            raise KeyboardInterrupt
    """)
    with pytest.raises(KeyboardInterrupt):
        parse_structure(_section(model=path))


def test_seft_simulate_on_a_script_that_exits_0_fails(tmp_path, seft_exe, run_process):
    """The real command on a script model ending in sys.exit(0): one error line, exit 2, no
    run (it ended with exit 0 and no output)."""
    (tmp_path / 'exits.py').write_text(
        "import openseespy.opensees as ops\nops.wipe(); ops.model('basic', '-ndm', 1, '-ndf', 1)"
        "\nimport sys; sys.exit(0)\n")
    (tmp_path / 'exits.yaml').write_text(
        'structure:\n  opensees:\n    model: exits.py\n    function: null\n'
        '    dofs: {s1: [1, 1]}\n    physical_elements: {lab: [1]}\n  physical: {s1: lab}\n')
    proc = run_process([seft_exe, 'simulate', 'exits.yaml', '--duration', '1', '--out', 'out'],
                       cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert 'Traceback' not in proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith('seft: error: ')]
    assert errors == ['seft: error: exits.yaml: structure.opensees.model: exits.py failed: '
                      'SystemExit: 0']
    assert not (tmp_path / 'out').exists()


def test_a_links_hysteresis_is_its_basic_force_on_its_deformation():
    """A zeroLength story of a 2-D model (ndf 2) loaded by 10 N along its direction: its
    recorded force is 10 N on 0.01 m (before: its first node's last DOF, the vertical force
    0, drawn as a flat line in the report; the shipped shear frame's too, session 38)."""
    from seft_ros.opensees.loader import opensees
    from seft_ros.opensees.part import element_response
    ops = opensees()
    ops.wipe()
    ops.model('basic', '-ndm', 2, '-ndf', 2)
    ops.node(1, 0.0, 0.0)
    ops.node(2, 0.0, 0.0)
    ops.fix(1, 1, 1)
    ops.fix(2, 0, 1)
    ops.uniaxialMaterial('Elastic', 1, 1000.0)
    ops.element('zeroLength', 1, 1, 2, '-mat', 1, '-dir', 1)
    ops.timeSeries('Linear', 1)
    ops.pattern('Plain', 1, 1)
    ops.load(2, 10.0, 0.0)
    for command in (('system', 'BandGeneral'), ('numberer', 'Plain'), ('constraints', 'Plain'),
                    ('integrator', 'LoadControl', 1.0), ('algorithm', 'Linear'),
                    ('analysis', 'Static')):
        getattr(ops, command[0])(*command[1:])
    assert ops.analyze(1) == 0
    force, deformation = element_response(ops, 1)
    assert force == pytest.approx(10.0) and deformation == pytest.approx(0.01)
    ops.wipe()


def test_what_opensees_says_while_a_model_builds_is_said_before_the_run(tmp_path):
    """A model that builds with OpenSees' warnings (a zeroLength story whose nodes are 3 m
    apart): one note line before the run, quoting the first and counting the rest (they
    were dropped; a new user, session 38); the shipped two-story model says nothing."""
    apart = _model(tmp_path, TWO_STORY.read_text().replace('ops.node(i, 0.0)',
                                                           'ops.node(i, 3.0 * i)'))
    base = expand_runs({'predictor': 'model'})[0]
    lines = []
    check_runs([dict(base, structure=parse_structure(_section(model=apart)).to_json())],
               progress=lines.append)
    assert lines == ['note: opensees: model.py:build: OpenSees said while the model built: '
                     'WARNING ZeroLength::setDomain(): Element 1 has L= 3, which is greater '
                     'than the tolerance (and 1 more line(s))']
    lines.clear()
    check_runs([dict(base, structure=parse_structure(_section()).to_json())],
               progress=lines.append)
    assert lines == []
