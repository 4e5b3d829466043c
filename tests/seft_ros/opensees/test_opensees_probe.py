"""seft_ros.opensees.probe: where an OpenSees computational part first yields, found by a
pushover of the model before the test, against the members' closed-form yield points."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from seft_ros.cli.config import expand_runs, load_config
from seft_ros.core.structure import test_setup
from seft_ros.opensees.loader import opensees
from seft_ros.opensees.part import OpenSeesPart
from seft_ros.opensees.report import pushover_entry, pushover_lines

ROOT = Path(__file__).resolve().parents[3]
K = 2.11e5                                   # each story's stiffness [N/m]

#: config/opensees/shear_frame.py with story 2 of another material: ``Steel01`` (3200 N, b
#: 0.02), ``ElasticPP`` yielding at a drift of +15 mm and -5 mm, ``Steel02`` (3200 N,
#: yielding gradually) or ``Elastic``.
FRAME = """
import openseespy.opensees as ops

def build(story2='Steel01'):
    ops.wipe()
    ops.model('basic', '-ndm', 2, '-ndf', 2)
    ops.node(0, 0.0, 0.0)
    ops.fix(0, 1, 1)
    for i in (1, 2, 3):
        ops.node(i, 0.0, 0.0)
        ops.fix(i, 0, 1)
        ops.mass(i, 52.7, 0.0)
        if i != 2 or story2 == 'Elastic':
            ops.uniaxialMaterial('Elastic', 10 + i, 2.11e5)
        elif story2 == 'Steel01':
            ops.uniaxialMaterial('Steel01', 12, 3200.0, 2.11e5, 0.02)
        elif story2 == 'ElasticPP':
            ops.uniaxialMaterial('ElasticPP', 12, 2.11e5, 0.015, -0.005)
        else:
            ops.uniaxialMaterial('Steel02', 12, 3200.0, 2.11e5, 0.02, 18.0, 0.925, 0.15)
        ops.element('zeroLength', i, i - 1, i, '-mat', 10 + i, '-dir', 1)
"""


def _params(tmp_path, story2: str, **section) -> dict:
    """The run parameters of the frame (story 1 the specimen; `section`: more keys of its
    ``structure.opensees``)."""
    tmp_path.mkdir(exist_ok=True)
    (tmp_path / 'frame.py').write_text(FRAME)
    doc = yaml.safe_load((ROOT / 'config' / 'opensees' / 'shear_frame.yaml').read_text())
    doc['structure']['opensees'].update(model='frame.py', arguments={'story2': story2},
                                        **section)
    path = tmp_path / 'frame.yaml'
    path.write_text(yaml.safe_dump(doc))
    return expand_runs(dict(load_config(path), duration_s=1.0))[0]


def _part(tmp_path, story2: str, **section) -> OpenSeesPart:
    """The frame's computational part, prepared: pushed over (unless `section` says not)."""
    params = _params(tmp_path, story2, **section)
    part = OpenSeesPart(test_setup(params).substructures, 0.002)
    part.prepare()
    return part


@pytest.mark.parametrize('story2, lam, low, high', [
    ('Steel01', 0.98 * 2 * K, -3200.0 / K, 3200.0 / K),
    ('ElasticPP', 2 * K, -0.005, 0.015)], ids=['steel01', 'elastic-perfectly-plastic'])
def test_a_bilinear_story_is_found_where_it_yields(tmp_path, story2, lam, low, high):
    """Story 2 between floors 1 and 2 (deformation x2 - x1: direction u = (-1, 1, 0)/sqrt 2,
    z = (x2 - x1)/sqrt 2) yields at its yield drift in each sense (asymmetric for the
    elastic-perfectly-plastic one), its deficit stiffness (1 - b) k |(-1, 1, 0)|^2: found by
    the pushes of floors 1 and 2 to 1e-9; floor 3's pushes stay linear (story 2 is not
    deformed)."""
    part = _part(tmp_path, story2)
    (mech,) = part.virgin_mechanisms
    sign = np.sign(mech.direction[1])
    np.testing.assert_allclose(sign * mech.direction, np.array([-1.0, 1.0, 0.0]) / np.sqrt(2),
                               atol=1e-9)
    assert mech.deficit_N_per_m == pytest.approx(lam, rel=1e-9)
    found = sorted(sign * v for v in (mech.low_m, mech.high_m))
    np.testing.assert_allclose(found, [low / np.sqrt(2), high / np.sqrt(2)], rtol=1e-9)
    assert mech.bilinear
    pushes = {(p.dof, p.sense): p for p in part.pushes}
    assert len(pushes) == 6
    assert pushes[(2, 1.0)].direction is None and pushes[(2, -1.0)].direction is None
    assert all(pushes[(d, s)].direction is not None for d in (0, 1) for s in (1.0, -1.0))
    # the test's model is built again after the pushes: without the specimen, at rest
    ops = opensees()
    assert sorted(ops.getEleTags()) == [2, 3]
    assert [ops.nodeDisp(n, 1) for n in (1, 2, 3)] == [0.0, 0.0, 0.0]
    assert part.tangent() is None


def test_a_gradual_story_is_found_but_not_anticipated_and_an_elastic_one_not_found(tmp_path):
    (mech,) = _part(tmp_path / 'a', 'Steel02').virgin_mechanisms
    assert not mech.bilinear
    assert _part(tmp_path / 'b', 'Elastic').virgin_mechanisms == []


def test_the_summary_says_what_the_pushover_found(tmp_path):
    """The run summary's entry (``opensees.pushover``, for the report and the console): the
    asymmetric story along the drift ``x2 - x1``, yielding at -5 and +15 mm and losing its
    whole stiffness 2.11e5 N/m (closed form); not run with ``pushover: false`` (nor does the
    part push) or with ``prediction: initial``."""
    entry = pushover_entry(_params(tmp_path / 'a', 'ElasticPP'))
    (mech,) = entry['mechanisms']
    assert entry['ran'] and entry['time_s'] > 0.0
    assert mech['coordinate'].keys() == {'floor_1', 'floor_2'}
    assert mech['coordinate']['floor_2'] == 1.0
    assert mech['coordinate']['floor_1'] == pytest.approx(-1.0, rel=1e-9)
    np.testing.assert_allclose(mech['first_yield_m'], [-0.005, 0.015], rtol=1e-9)
    assert mech['lost_stiffness_N_per_m'] == pytest.approx(K, rel=1e-9)
    assert mech['bilinear']
    lines = pushover_lines(entry)
    assert len(lines) == 2 and lines[0].endswith('1 yielding mechanism(s)')
    assert lines[1].startswith('  -floor_1 + floor_2: first yields at -5.00 / +15.00 mm, '
                               'bilinear (loses 2.11e+05 N/m)'), lines[1]
    assert pushover_entry(_params(tmp_path / 'b', 'ElasticPP', pushover=False)) == {
        'ran': False, 'why': 'pushover: false'}
    assert _part(tmp_path / 'c', 'ElasticPP', pushover=False).virgin_mechanisms is None
    assert pushover_entry(_params(tmp_path / 'd', 'ElasticPP', prediction='initial')) == {
        'ran': False, 'why': 'prediction: initial'}


def test_the_summary_takes_what_the_runs_part_found_without_pushing_again(tmp_path,
                                                                           monkeypatch):
    """The part's own findings (what the builder hands on in the run's data) are the summary
    entry's, mechanism for mechanism; a run that carries them is summarised without a second
    pushover (the pushover made to fail here), and one recorded without them (an older bag)
    is pushed again."""
    from seft_ros.opensees import report
    params = _params(tmp_path / 'a', 'ElasticPP')
    findings = _part(tmp_path / 'b', 'ElasticPP').findings()
    found = findings['pushover']
    assert found['ran'] and found['mechanisms'] == pushover_entry(params)['mechanisms']
    assert _part(tmp_path / 'c', 'ElasticPP', pushover=False).findings() == {
        'pushover': {'ran': False, 'why': 'pushover: false'}}
    # a run's data as the builder hands them on (seft simulate's RunData.extra, a bag's
    # builder status: tests/seft_ros/test_structure_graph.py)
    run = SimpleNamespace(params=params, extra={'part_findings': findings})

    def pushed(*args, **kwargs):
        raise AssertionError('pushed over again')
    monkeypatch.setattr(report, 'probe_yield', pushed)
    assert report.run_pushover(run) == run.extra['part_findings']['pushover']
    run.extra.pop('part_findings')
    with pytest.raises(AssertionError, match='pushed over again'):
        report.run_pushover(run)
