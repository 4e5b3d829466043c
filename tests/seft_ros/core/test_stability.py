"""Tests of the stability map (sampled-loop eigenvalues) against independent references and
against simulation."""

import json
import math
import re

import numpy as np
import pytest
from scipy import signal

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_plant_sim.servohydraulic import (
    ServoHydraulicParams,
    stability_boundary_alpha,
    substructure_spectral_radius,
)
from seft_plant_sim.specimen import LinearSpecimen
from seft_ros.core import stability as st
from seft_ros.core.controller import ForceServoController
from seft_ros.core.experiment import simulate
from seft_ros.core.reference_force import PREDICTORS
from seft_ros.core.structure import parse_structure, test_setup


@pytest.fixture(scope='module')
def delay_params(reference_params):
    return dict(reference_params, rig_model='delay', predictor='none')


@pytest.fixture(scope='module')
def free_response(reference_params, tmp_path_factory):
    """Parameters of a free-response run: a 6 ms ground pulse then 4 s of nothing, no monitor
    nor divergence guard, no interlock, no limits in reach, unlimited valve and
    accelerometer."""
    path = tmp_path_factory.mktemp('stability') / 'pulse.csv'
    t = np.arange(2000) * 0.002
    ag = np.zeros_like(t)
    ag[1:4] = 1.0
    np.savetxt(path, np.c_[t, ag], delimiter=',')
    return dict(reference_params, record=str(path), time_scale=1.0, amplitude_N=100.0,
                monitor_threshold=0.0, divergence_factor=0.0, saturation_abort_fraction=1.0,
                stroke_limit_m=1e3,
                force_limit_N=1e12, valve_limit_V=100.0, accelerometer_range_m_s2=0.0,
                # the preview (on by default) would command the pulse tau ahead: a pulse in
                # the first tau of the record would then never be applied (nothing is
                # commanded before t = 0); the stability is the feedback loop's either way
                ground_preview=False)


def growth(params) -> float:
    """max|x| over the last second / max|x| over the first second of a free response."""
    run = simulate(params)
    assert run.n_steps == 2000, run.abort_reason
    x = np.abs(run.displacement_m)
    return float(np.max(x[-500:]) / np.max(x[:500]))


def delay_roots_radius(params, alpha: float) -> float:
    """Independent reference, delay rig with tau = n dt: the roots of the characteristic
    polynomial ``z^(n+1) den(z) + alpha m num(z)`` with ``num/den`` the ZOH pulse transfer
    function from the held actuator force to the acceleration sampled at t_k+."""
    m, c, k = params['mass_kg'], params['damping_N_s_per_m'], params['stiffness_N_per_m']
    dt = params['dt']
    n = int(round(params['tau_s'] / dt))
    assert abs(n * dt - params['tau_s']) < 1e-12
    sysd = signal.cont2discrete((np.array([[0.0, 1.0], [-k / m, -c / m]]),
                                 np.array([[0.0], [1.0 / m]]), np.array([[-k / m, -c / m]]),
                                 np.array([[1.0 / m]])), dt, 'zoh')
    num, den = signal.ss2tf(*sysd[:4])
    num, den = np.ravel(num), np.ravel(den)            # same degree (feedthrough 1/m)
    poly = np.polyadd(np.concatenate([den, np.zeros(n + 1)]), alpha * m * num)
    return float(np.max(np.abs(np.roots(poly))))


# -- delay rig, no compensation: the neutral-type loop (paper Eq. 5.4) --------------------------

@pytest.mark.parametrize('tau', [0.004, 0.01, 0.02])
def test_delay_none_matches_characteristic_polynomial(delay_params, tau):
    p = dict(delay_params, tau_s=tau)
    for alpha in (0.3, 0.8, 0.95, 1.2):
        assert st.spectral_radius(p, alpha) == pytest.approx(delay_roots_radius(p, alpha),
                                                              rel=1e-9)


@pytest.mark.parametrize('tau', [0.004, 0.01, 0.02])
def test_delay_none_is_unstable_above_one_for_every_tau(delay_params, tau):
    p = dict(delay_params, tau_s=tau)
    boundary = st.largest_stable_alpha(p)
    assert boundary <= 1.0 + 1e-3
    # the first root chain crosses near exp(-(w_n T / pi)^2), T = tau + dt (module notes)
    w_n = math.sqrt(p['stiffness_N_per_m'] / p['mass_kg'])
    estimate = math.exp(-(w_n * (tau + p['dt']) / math.pi) ** 2)
    assert boundary == pytest.approx(estimate, abs=0.04)
    assert st.spectral_radius(p, 1.01) > 1.0


@pytest.mark.parametrize('tau', [0.004, 0.01])
def test_delay_none_alpha_0_9_is_stable(delay_params, tau):
    assert st.spectral_radius(dict(delay_params, tau_s=tau), 0.9) < 1.0


def test_delay_none_alpha_0_9_is_unstable_at_20_ms(delay_params):
    """With the specimen's stiffness the boundary drops below 1 as the delay grows."""
    p = dict(delay_params, tau_s=0.02)
    assert st.largest_stable_alpha(p) == pytest.approx(0.813, abs=2e-3)
    assert st.spectral_radius(p, 0.9) > 1.0


def test_a_delay_that_rounds_to_none_is_one_parameter_error(delay_params):
    """tau_s under 1e-9 dt is no delay (the rig refuses it, test_delay_rig.py): the model of
    the pre-run check says so in the rig's words (it failed with an IndexError, a traceback
    from every seft simulate and seft run of such a tau)."""
    with pytest.raises(ParameterError, match=r'^parameter tau_s=1e-12: expected float > 0 '):
        st.loop_model(dict(delay_params, tau_s=1e-12))


def test_delay_none_neutral_limit_over_a_range_of_delays(delay_params):
    smap = st.stability_map(delay_params, np.linspace(0.0005, 0.02, 40), ['none'])
    curve = smap.boundary('none')
    assert curve.shape == (40,) and np.all(np.isfinite(curve))
    assert np.all(curve < 1.0 + 0.005) and np.all(curve > 0.8)   # 1.0035 at 0.5 ms (sampled)
    assert smap.delay_parameter == 'tau_s' and smap.notes == {}


# -- servohydraulic rig, no compensation ------------------------------------------------------

def test_servohydraulic_none_matches_the_rig_model(reference_params):
    p = dict(reference_params, predictor='none')
    spec = LinearSpecimen.from_parameters(p)
    ctrl = ForceServoController(0.002)
    hp = ServoHydraulicParams()
    assert st.largest_stable_alpha(p) == pytest.approx(
        stability_boundary_alpha(hp, spec, ctrl), abs=2e-4)
    assert st.largest_stable_alpha(p) == pytest.approx(1.317, abs=1e-3)
    for alpha in (0.0, 0.7, 1.5):
        assert st.spectral_radius(p, alpha) == pytest.approx(
            substructure_spectral_radius(hp, spec, ctrl, alpha), rel=1e-9)


def test_servohydraulic_map_over_io_latency(reference_params):
    smap = st.stability_map(dict(reference_params, predictor='none'), [0.0, 0.003, 0.02],
                            ['none'])
    assert smap.delay_parameter == 'io_latency_s'
    b = smap.boundary('none')
    assert b[0] == pytest.approx(2.545, abs=2e-3)       # servohydraulic.py: 2.54 without it
    assert b[1] == pytest.approx(1.317, abs=1e-3)
    assert math.isnan(b[2])                              # force loop unstable at alpha = 0
    doc = json.loads(json.dumps(smap.to_json()))
    assert doc['predictors']['none']['boundary_alpha'][2] is None


# -- against simulation ----------------------------------------------------------------------

@pytest.mark.parametrize('rig, tau_key, tau, predictor, extra', [
    ('delay', 'tau_s', 0.01, 'none', {}),
    ('delay', 'tau_s', 0.011, 'none', {}),               # fractional delay, split step
    ('servohydraulic', 'io_latency_s', 0.003, 'none', {}),
    ('delay', 'tau_s', 0.01, 'polynomial', {'polynomial_order': 1}),
])
def test_boundary_against_simulation(free_response, rig, tau_key, tau, predictor, extra):
    p = dict(free_response, rig_model=rig, predictor=predictor, **{tau_key: tau}, **extra)
    boundary = st.largest_stable_alpha(p)
    assert 0.0 < boundary < 3.0
    inside, outside = 0.95 * boundary, 1.05 * boundary
    assert st.spectral_radius(p, inside) < 1.0 < st.spectral_radius(p, outside)
    assert growth(dict(p, alpha=inside)) < 0.1
    assert growth(dict(p, alpha=outside)) > 10.0


def test_model_compensator_moves_the_boundary(free_response):
    p = dict(free_response, rig_model='delay', predictor='model')
    comp = st.compensator(p)
    assert comp.alpha_dependent                          # pole matching depends on alpha
    assert st.largest_stable_alpha(p) == math.inf        # stable up to alpha_max = 3
    assert st.spectral_radius(p, 3.0) < 1.0
    assert growth(dict(p, alpha=3.0)) < 0.1


# -- compensator forms -------------------------------------------------------------------------

class FakeFir:
    """A linear compensator with memory and a command filter, known taps."""

    name = 'fake_fir'

    def __init__(self):
        self.acc = [0.0, 0.0]
        self.sent = [0.0]

    @classmethod
    def from_parameters(cls, params):
        return cls()

    def predict(self, latest, commanded_N, ground_force_N=0.0):
        if latest is not None:
            self.acc = [latest.acceleration_m_s2, self.acc[0]]
        force = commanded_N[-1] if commanded_N else 0.0
        x = latest.displacement_m if latest is not None else 0.0
        return 1.5 * self.acc[0] - 0.5 * self.acc[1] + 2.0 * x + 1e-4 * force

    def command(self, force_N):
        out = 0.75 * force_N + 0.25 * self.sent[0]
        self.sent = [force_N]
        return out


class FakeSquare(FakeFir):
    name = 'fake_square'

    def predict(self, latest, commanded_N, ground_force_N=0.0):
        return 0.0 if latest is None else latest.acceleration_m_s2 ** 2


class FakeStated(FakeFir):
    """States its own form (the LinearPredictor protocol)."""

    name = 'fake_stated'

    def linear_form(self):
        return st.PredictorForm.fir([[2.0, 0.0], [0.0, 0.0], [1.5, -0.5], [0.0, 0.0], [1e-4, 0.0]],
                                    [0.75, 0.25])


@pytest.fixture
def fakes(monkeypatch):
    for cls in (FakeFir, FakeSquare, FakeStated):
        monkeypatch.setitem(PREDICTORS, cls.name, cls.from_parameters)


def test_identified_form_equals_the_stated_one(fakes, delay_params):
    fir = st.compensator(dict(delay_params, predictor='fake_fir'))
    stated = st.compensator(dict(delay_params, predictor='fake_stated'))
    assert not fir.alpha_dependent and not stated.alpha_dependent
    f, g = fir.form(1.0), stated.form(1.0)
    assert f.source == 'identified' and g.source == 'linear_form'
    for name in ('a', 'b', 'c', 'd', 'cmd_a', 'cmd_b', 'cmd_c'):
        np.testing.assert_allclose(getattr(f, name), getattr(g, name), rtol=1e-9, atol=1e-15,
                                   err_msg=name)
    assert f.cmd_d == pytest.approx(0.75)
    for alpha in (0.2, 0.6):
        assert st.spectral_radius(dict(delay_params, predictor='fake_fir'), alpha) == \
            pytest.approx(st.spectral_radius(dict(delay_params, predictor='fake_stated'),
                                             alpha), rel=1e-9)


def test_none_identified_equals_analytic(delay_params):
    taps, cmd = st._identify(PREDICTORS['none'](delay_params), 'none', 0.002, True)
    form = st.PredictorForm.fir(taps, cmd)
    np.testing.assert_array_equal(form.d, st.PredictorForm.none().d)
    assert form.order == 0 and form.command_order == 0 and form.cmd_d == 1.0


def test_a_command_of_forces_alone_is_identified_without_driving_it_again(reference_params,
                                                                        monkeypatch):
    """`model` on the servohydraulic rig (its command the force-loop inverse's FIR of the
    desired forces alone): the probes of the measurements skip the command, and the taps are
    the same floats as when every probe drives it (the drives computed at once,
    ``drive_responses``, or stepped)."""
    from seft_ros.core.reference_force import make_predictor
    pred = make_predictor(dict(reference_params, predictor='model', alpha=1.0))
    assert type(pred).command_of_forces_only is True and pred.loop_inverse is not None
    calls = []
    step = type(pred.loop_inverse).step
    at_once = type(pred).drive_responses

    def counted(self, force_n):
        calls.append(1)
        return step(self, force_n)

    def counted_at_once(self, inputs, command=True):
        calls.extend([1] * (inputs.shape[0] if command else 0))
        return at_once(self, inputs, command)

    monkeypatch.setattr(type(pred.loop_inverse), 'step', counted)
    monkeypatch.setattr(type(pred), 'drive_responses', counted_at_once)
    taps, cmd = st._identify(pred, 'model', 0.002, True)
    skipped = len(calls)
    calls.clear()
    monkeypatch.setattr(type(pred), 'command_of_forces_only', False)
    taps_all, cmd_all = st._identify(pred, 'model', 0.002, True)
    np.testing.assert_array_equal(taps, taps_all)
    np.testing.assert_array_equal(cmd, cmd_all)
    assert np.count_nonzero(cmd) > 10
    n = st._WARM_UP + st._WINDOW
    assert skipped == len(calls) - 5 * n             # 5 of the 6 probes left the command out
    calls.clear()
    monkeypatch.setattr(type(pred), 'drive_responses', lambda *args: None)    # stepped
    taps_stepped, cmd_stepped = st._identify(pred, 'model', 0.002, True)
    assert taps_stepped.tobytes() == taps.tobytes() and cmd_stepped.tobytes() == cmd.tobytes()
    assert len(calls) == 7 * n + 2 * (st._WARM_UP + 2 * st._WINDOW)    # stepped: step


def test_the_model_predictors_steps_at_once_are_its_stepped_floats(reference_params):
    """``ModelPredictor.drive_responses`` (the identification's drives computed for all steps
    at once) gives the floats of stepping a copy, bit for bit: on zeros, a pulse of each
    input and random inputs, with the law's gains calibrated, a loop inverse that has
    filtered forces before and at alpha 0; a law it does not cover is stepped."""
    from seft_ros.core.predictors import ModelPredictor
    from seft_ros.core.reference_force import make_predictor
    base = make_predictor(dict(reference_params, predictor='model', alpha=1.0))
    offset = make_predictor(dict(reference_params, predictor='model', alpha=0.5,
                                 predictor_loop_delay_steps=7))
    offset = ModelPredictor(offset.model, 0.5, offset.mass_kg, offset.loop_inverse,
                            gain_offset=(1.5e3, -40.0, 1.01))
    used = make_predictor(dict(reference_params, predictor='model', alpha=1.5))
    for force in (300.0, -120.0, 45.0):
        used.command(force)                   # a filter state to start from
    rest = ModelPredictor(base.model, 0.0, base.mass_kg, base.loop_inverse)
    n, rng = 260, np.random.default_rng(3)
    inputs = [np.zeros((n, 6)), rng.standard_normal((n, 6)) * st._PROBE_SCALE]
    for i in range(6):
        pulse = np.zeros((n, 6))
        pulse[16, i] = st._PROBE_SCALE[i]
        inputs.append(pulse)
    for pred in (base, offset, used, rest):
        for q in inputs:
            for command in (True, False):
                got = pred.drive_responses(q, command)
                want = st._stepped(pred, q, 0.002, command)
                assert got[0].tobytes() == want[0].tobytes()
                assert (got[1] is None and want[1] is None
                        or got[1].tobytes() == want[1].tobytes())
    assert np.count_nonzero(used.drive_responses(inputs[0])[1]) > 10     # the state's
    impulse = ModelPredictor(base.model, 1.0, base.mass_kg, base.loop_inverse,
                             matching='impulse')
    measured = ModelPredictor(base.model, 1.0, base.mass_kg, base.loop_inverse,
                              restoring_force='measured')
    assert impulse.drive_responses(inputs[1]) is None
    assert measured.drive_responses(inputs[1]) is None


def test_nonlinear_compensators_have_no_form(fakes, delay_params):
    with pytest.raises(st.NoLinearModelError, match="'fake_square': not linear"):
        st.compensator(dict(delay_params, predictor='fake_square'))
    with pytest.raises(st.NoLinearModelError, match="'adaptive' is nonlinear"):
        st.compensator(dict(delay_params, predictor='adaptive'))
    smap = st.stability_map(delay_params, [0.01], ['none', 'adaptive'])
    assert 'adaptive' in smap.notes and np.isnan(smap.boundary('adaptive')).all()
    assert smap.boundary('none')[0] == pytest.approx(0.932, abs=1e-3)


# -- the pre-run check -------------------------------------------------------------------------

def test_check_run(reference_params):
    bad = st.check_run(dict(reference_params, alpha=1.5))
    assert bad.stable is False and bad.spectral_radius > 1.0
    assert bad.message == ('alpha=1.5 with predictor none on the servohydraulic rig is '
                           'predicted unstable (largest stable alpha 1.32)')
    ok = st.check_run(dict(reference_params, alpha=1.0))
    assert ok.stable is True and ok.spectral_radius < 1.0
    assert ok.boundary_alpha == pytest.approx(1.317, abs=1e-3)
    skipped = st.check_run(dict(reference_params, alpha=1.5, specimen_model='bouc_wen',
                                predictor='model', predictor_restoring_force='hysteretic'))
    assert skipped.stable is None and 'not linear time-invariant' in skipped.message
    # both figures of the superposition test, each beside the response it is of
    assert re.search(r'misses the sum of its impulse responses by \S+ m/s\^2 in the predicted '
                     r'acceleration, of \S+, and \S+ N in the command, of \S+\)',
                     skipped.message), skipped.message
    skipped = st.check_run(dict(reference_params, alpha=1.5, predictor='adaptive'))
    assert skipped.stable is None and 'not predicted' in skipped.message


def test_largest_stable_dt_of_the_force_loop():
    """The servohydraulic force loop alone (alpha = 0) at a too-long sample period: the
    bisection's period is stable, 2 % longer is not, and the default 2 ms is stable."""
    from seft_msgs_py import parameters
    assert st.largest_stable_dt(parameters.resolve({})) == math.inf
    p = parameters.resolve({'dt': 0.01})
    dt = st.largest_stable_dt(p)
    assert 0.006 < dt < 0.008                      # check_run: 6 ms stable, 8 ms unstable

    def rho(d):
        q = dict(p, dt=d, alpha=0.0)
        return float(st.LoopModel(q, st.compensator(q)).radii(0.0)[0])
    assert rho(dt) < 1.0 < rho(1.02 * dt)
    check = st.check_run(p)
    assert check.stable is False
    assert check.message.startswith('parameter dt=0.01: the force loop alone (alpha = 0, no '
                                    'mass fed back) is predicted unstable on the '
                                    'servohydraulic rig: the sample period is too long')


# -- structures: the whole loop, the coupling scale --------------------------------------------

M_S, K_S, C_S = 52.7, 2.11e5, 903.278


def _two_story(mu, fr, predictor, rig='servohydraulic', **rig_section):
    m2, k2 = mu * M_S, mu * fr ** 2 * K_S
    s = parse_structure({'dofs': ['s1', 's2'], 'physical': {'s1': 'lab'},
                         'story_masses_kg': [M_S, m2], 'story_stiffnesses_N_per_m': [K_S, k2],
                         'story_damping_N_s_per_m': [C_S, 0.04 * np.sqrt(k2 * m2)]},
                        rigs={'lab': dict(rig_model=rig, **rig_section)})
    return parameters.resolve({'structure': s.to_json(), 'predictor': predictor,
                               'duration_s': 20.0, 'monitor_threshold': 0.0})


@pytest.mark.parametrize('rig', ['servohydraulic', 'delay'])
def test_the_rigid_limit_has_the_studys_boundary(rig):
    """One physical DOF carrying the rigid mass alpha m = m: the coupling scale is alpha, and
    uncompensated the boundary is the study's largest stable alpha (1.32 / 0.93)."""
    s = parse_structure({'physical': {'floor_1': 'lab'}, 'story_masses_kg': [2 * M_S],
                         'story_stiffnesses_N_per_m': [K_S], 'story_damping_N_s_per_m': [C_S]},
                        rigs={'lab': {'rig_model': rig}})
    p = parameters.resolve({'structure': s.to_json(), 'predictor': 'none'})
    study = st.largest_stable_alpha(parameters.resolve(
        {'alpha': 1.0, 'predictor': 'none', 'rig_model': rig}))
    assert st.largest_stable_scale(p, step=0.05, tol=1e-4) == pytest.approx(study, abs=2e-4)


def test_scaling_keeps_the_specimens_and_scales_the_rest():
    p = _two_story(1.0, 2.0, 'model')
    sub = test_setup(st.scaled_parameters(p, 0.5)).substructures
    whole = test_setup(p).substructures
    assert sub.specimen_stiffness_N_per_m == pytest.approx(whole.specimen_stiffness_N_per_m)
    np.testing.assert_allclose(sub.stiffness_c_N_per_m, 0.5 * whole.stiffness_c_N_per_m)
    np.testing.assert_allclose(sub.mass_c_kg, 0.5 * whole.mass_c_kg)
    with pytest.raises(parameters.ParameterError, match='coupling scale 0: expected > 0'):
        st.scaled_parameters(p, 0)


def _grows(params) -> bool:
    """Stepped (monitor off): the story's motion still near its peak in the record's quiet
    end, or a limit reached."""
    run = simulate(params)
    x = run.rigs['lab'].displacement_m
    return (not run.stable) or np.max(np.abs(x[-1000:])) > 0.5 * np.max(np.abs(x))


@pytest.mark.parametrize('mu, fr, predictor, stable', [
    (1.0, 1.0, 'model', True),
    (1.5, 3.0, 'model', False),     # the second mode at 48 Hz, beyond the force loop's band
    (0.5, 0.5, 'none', True),       # a soft coupling survives the delay's negative damping
    (1.0, 1.0, 'none', False),
])
def test_the_guard_says_what_the_stepped_run_does(mu, fr, predictor, stable):
    p = _two_story(mu, fr, predictor)
    radius = st.TestLoop(p).spectral_radius
    assert (radius < 1.0) == stable
    assert _grows(p) == (not stable)


def test_check_structure_says_it_in_one_line():
    check = st.check_run(_two_story(1.0, 1.0, 'none'))
    assert check.stable is False
    assert check.message.startswith('structure with predictor none is predicted UNSTABLE '
                                    '(spectral radius 1.0')
    ok = st.check_run(_two_story(1.0, 1.0, 'model'))
    assert ok.stable and 'predicted stable' in ok.message


@pytest.mark.parametrize('k2, grows_hz, mode_hz, nyquist', [
    (1e7, 107.0, 102.9, False), (1e8, 250.0, 324.9, True)])
def test_a_stiff_link_is_named_where_the_test_grows(k2, grows_hz, mode_hz, nyquist, tmp_path):
    """A two-story whose second story is stiff (session 23's D9: 1e8 N/m, a 325 Hz mode
    above the 250 Hz Nyquist frequency): the refusal says where the loop grows, the mode it
    is, and the cause (before: the spectral radius and the coupling scale only); a stepped
    run is stopped by the instability monitor (at 0.32 s and 0.07 s)."""
    from seft_ros.cli.api import build_runs
    config = tmp_path / 'stiff.yaml'
    config.write_text(f"""\
predictor: model
amplitude_N: 800.0
time_scale: 0.5
duration_s: 1.0
structure:
  dofs: [f1, f2]
  physical: {{f1: lab}}
  story_masses_kg: [60.0, 40.0]
  story_stiffnesses_N_per_m: [2.5e5, {k2}]
  story_damping_N_s_per_m: [950.0, 150.0]
rigs:
  lab: {{rig_model: servohydraulic, stiffness_N_per_m: 2.5e5,
         force_controller: specimen_loop_shaping}}
""")
    p = build_runs(config=str(config), overrides={})[0]
    check = st.check_run(p)
    assert check.stable is False
    m = re.search(r'; it grows at ([\d.]+) Hz, the structure\'s mode at ([\d.]+) Hz(, above '
                  r'the Nyquist frequency 250 Hz of dt=0.002 s)? \(its modes: [\d.]+, '
                  r'[\d.]+ Hz\): a stiff computational link \(a near-rigid story, a bearing\) '
                  r'puts a mode where one sample period costs its feedback 45 degrees or more; '
                  r'lump the DOFs it joins into one, or soften it$', check.message)
    assert m, check.message
    assert float(m[1]) == pytest.approx(grows_hz, abs=0.5)
    assert float(m[2]) == pytest.approx(mode_hz, abs=0.1)
    assert (m[3] is not None) == nyquist
    # the mode against the structure's own eigenvalues (independent of the loop)
    w2 = np.linalg.eigvals(np.linalg.solve(np.diag([60.0, 40.0]), [[2.5e5 + k2, -k2],
                                                                    [-k2, k2]]))
    assert float(m[2]) == pytest.approx(np.sqrt(w2.max()) / (2 * math.pi), rel=1e-3)
    run = simulate(p)
    assert not run.stable and 'high-frequency oscillation' in run.abort_reason
    # an uncompensated two-story grows at its second mode, 12 Hz: named, with no stiff link
    slow = st.check_run(_two_story(1.0, 1.0, 'none'))
    assert 'it grows at' in slow.message and 'stiff' not in slow.message, slow.message


# -- the robustness margin ------------------------------------------------------------------

def test_the_margin_is_where_the_loop_turns_unstable_and_a_run_does():
    """The study's alpha = 1.5 with 'model': the margin's edges bracket the spectral radius
    crossing 1 (every rig's specimen scaled, the compensator keeping its model), and a
    stepped run with the specimen just outside the upper edge grows while one just inside
    holds."""
    p = parameters.resolve({'alpha': 1.5, 'predictor': 'model', 'duration_s': 8.0})
    margin = st.robustness_margin(p)
    assert 0.3 < margin.low < 0.45 and 1.6 < margin.high < 2.0
    comp = st.compensator(p)

    def radius(ratio):
        return float(st.LoopModel(p, comp, tangent_ratio=ratio).radii(1.5)[0])
    for edge in (margin.low, margin.high):
        inside = edge * (1.005 if edge < 1 else 0.995)
        outside = edge * (0.98 if edge < 1 else 1.02)
        assert radius(inside) < 1.0 < radius(outside)
    k = p['stiffness_N_per_m']

    def run(ratio):
        # the specimen ratio x as stiff as declared, the compensator's model the declared one
        return simulate(dict(p, stiffness_N_per_m=ratio * k, predictor_stiffness_N_per_m=k))
    assert run(0.95 * margin.high).stable
    assert not run(1.1 * margin.high).stable
    assert margin.covers(0.2) and not margin.covers(0.9)


def test_a_yielding_structure_is_checked_at_its_members_elastic_stiffness():
    """A structure whose members yield, on a linear compensator: its loop at the members'
    elastic stiffness, where every run starts, decides a refusal (the two piers yielding with
    `none`: spectral radius 1.03, as the elastic twin; before, no prediction, and a new
    user's yielding building with `none` started and diverged, session 36); stable there,
    no verdict, said so (`polynomial`); a nonlinear law, no prediction as before (`model`).
    Checked against a run: `none` diverges, as predicted."""
    from pathlib import Path

    from seft_ros.cli.api import build_runs
    config = str(Path(__file__).resolve().parents[3] / 'config' / 'two_piers_yielding.yaml')

    def run_of(predictor):
        return build_runs(config=config, overrides={'predictor': predictor,
                                                    'duration_s': 4.0})[0]
    none = st.check_run(run_of('none'))
    assert none.stable is False and none.spectral_radius == pytest.approx(1.0304, abs=1e-4)
    assert none.message.startswith(
        "structure with predictor none at its yielding members' elastic (initial) stiffness, "
        'where every run starts, is predicted UNSTABLE (spectral radius 1.0304); it grows at ')
    assert not simulate(run_of('none')).stable
    poly = st.check_run(run_of('polynomial'))
    assert poly.stable is None and poly.spectral_radius < 1.0
    assert ': stable (spectral radius 0.99' in poly.message
    assert poly.message.endswith("not predicted as they yield (specimen 'bouc_wen' is "
                                 'nonlinear)')
    model = st.check_run(run_of('model'))
    assert model.stable is None and model.message.startswith(
        'structure with predictor model: no stability prediction')


def test_the_margin_of_a_structure_and_of_adaptive():
    """two_piers with 'model': the whole loop's margin (both piers scaled together);
    'adaptive' compensates what it identifies (+-adaptive_max_deviation) and says what its
    initial law alone holds."""
    from seft_ros.cli.api import build_runs
    model = build_runs(config='config/two_piers.yaml', overrides={'predictor': 'model'})[0]
    margin = st.robustness_margin(model)
    assert 0.3 < margin.low < 0.45 and 1.1 < margin.high < 1.25
    assert st.TestLoop(model, stiffness_ratio=0.98 * margin.high).spectral_radius < 1.0
    assert st.TestLoop(model, stiffness_ratio=1.03 * margin.high).spectral_radius > 1.0
    adaptive = st.robustness_margin(dict(model, predictor='adaptive'))
    assert (adaptive.low, adaptive.high) == (0.5, 1.5)
    assert 'initial law' in adaptive.note and adaptive.note.endswith(
        margin.text(bare=True))
    unstable = st.robustness_margin(dict(model, predictor='none'))
    assert unstable.text() == 'no robustness margin: unstable as declared'


def test_adaptive_from_a_prior_its_model_law_cannot_use():
    """'adaptive' whose declared specimen (k 1.2, m 0.8 times the study's: 12.4 Hz) makes a
    loop with the study's controller that seft's rig model cannot invert: the guard's margin
    says the initial law is not predicted instead of raising the model law's error (which
    refused the run before it was built), and the run's own error names adaptive."""
    from seft_ros.cli.api import build_runs
    p = build_runs(overrides={'predictor': 'adaptive', 'alpha': 1.0, 'duration_s': 0.2,
                              'predictor_stiffness_N_per_m': 1.2 * 2.11e5,
                              'predictor_mass_kg': 0.8 * 52.7})[0]
    with pytest.raises(ParameterError, match='^predictor model on the servohydraulic rig: '):
        st.robustness_margin(dict(p, predictor='model'))
    margin = st.check_run(p, margin=True).margin
    assert (margin.low, margin.high) == (0.5, 1.5)
    assert ('its initial law, model at the declared specimen, alone: not predicted, the model '
            'law is not built for it (predictor model on the servohydraulic rig: ') in margin.note
    with pytest.raises(ParameterError, match=r'^predictor adaptive on the servohydraulic rig: '
                       r'the force loop .* is unstable \(closed-loop spectral radius 1\.003\): '
                       r'no loop to invert'):
        simulate(p)


def test_a_plant_gain_error_is_said_with_its_predicted_cost():
    """The margin of a test on a plant model of data says what a plant gain GAIN_ERROR off
    the model's costs (finite: predicted NRMS; inf: unstable there), in its text and JSON."""
    from seft_ros.core.stability import GAIN_ERROR, RobustnessMargin
    costly = RobustnessMargin(0.6, 1.4, '', 'plant_gain', 0.0787)
    assert costly.text().endswith(
        "; a plant gain 2 % off the model's costs 7.9 % NRMS x (predicted): identify the rig "
        'again when its supply pressure or oil temperature changes; predictor adaptive with '
        'adaptive_loop_fit fit follows the gain (measured on a 10 Hz specimen; docs: '
        'results/own-actuator)')
    assert costly.to_json()['gain_error_cost'] == 0.0787
    assert costly.to_json()['gain_error'] == GAIN_ERROR == 0.02
    unstable = RobustnessMargin(0.1, 1.007, '', 'plant_gain', math.inf)
    assert "2 % off the model's is unstable (predicted)" in unstable.text()
    assert unstable.to_json()['gain_error_cost'] is None
    assert unstable.to_json()['gain_error_unstable'] and not costly.to_json()[
        'gain_error_unstable']
    assert 'off the model' not in RobustnessMargin(0.5, 2.0).text()      # seft's rig model


# -- the force loop alone unstable: what to check (a lab's controller, its plant model) ------

def _lab_loop(gain: float = 0.05, scale_a: float = 1.0, **extra) -> dict:
    """seft's servohydraulic rig as a lab's discrete plant_model (its A scaled by
    `scale_a`) on the state_space rig, closed by a lab's proportional force controller of
    `gain` [V/N]."""
    from seft_ros.core.force_loop import force_loop_plant
    doc = force_loop_plant(parameters.resolve({})).to_mapping()
    doc['a'] = (scale_a * np.asarray(doc['a'])).tolist()
    doc['source'] = 'lab test model'
    ctl = json.dumps({'num': [gain], 'den': [1.0]})
    return parameters.resolve(dict({'rig_model': 'state_space', 'plant_model': json.dumps(doc),
                                    'force_controller': 'transfer_function',
                                    'force_controller_tf': ctl, 'predictor': 'none',
                                    'alpha': 0.5}, **extra))


def _closed_radius(p: dict) -> float:
    """The closed force loop's largest pole modulus by python-control: the plant's force
    output under unity feedback through the static gain."""
    import control

    from seft_ros.core.force_loop import force_loop_plant
    gain = json.loads(p['force_controller_tf'])['num'][0]
    lti = force_loop_plant(p).to_lti()
    force = control.ss(lti.A, lti.B, lti.C[:1], lti.D[:1], lti.dt)
    return float(np.max(np.abs(control.poles(control.feedback(gain * force, 1)))))


def _model_refuses(p: dict, expected: str) -> None:
    """Predictor model's force-loop inverse refuses the loop of `p` with the guard's
    `expected` message, before simulating it: no numpy warning (overflow) on the way."""
    import warnings

    from seft_ros.core.predictors import ForceLoopInverse
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        with pytest.raises(ParameterError) as err:
            ForceLoopInverse.from_parameters(dict(p, predictor='model'))
    assert str(err.value) == expected + '; predictor model has no loop to invert'


def test_an_unstable_lab_controller_is_named_not_dt():
    """A proportional gain of 0.05 V/N on seft's rig as a plant model: the guard names
    force_controller_tf with the closed loop's spectral radius (python-control's poles),
    not the sample period; predictor model refuses it in the same words before simulating
    the loop (no numpy overflow warning)."""
    p = _lab_loop()
    radius = _closed_radius(p)
    assert radius > 1.5
    check = st.check_run(p)
    assert check.stable is False
    expected = ('parameter force_controller_tf: the force loop alone (alpha = 0, no mass fed '
                'back) is predicted unstable on the state_space rig with this force controller '
                f'(closed-loop spectral radius {radius:.4g}), and no shorter dt makes it '
                'stable: expected a force controller that stabilizes its plant model (lab test '
                'model); design one with seft design')
    assert check.message == expected
    _model_refuses(p, expected)
    # adaptive identifies the specimen, not the loop: no margin (before, it claimed its
    # identification's range, 0.5-1.5 x, on the line before the run was refused)
    margin = st.robustness_margin(dict(p, predictor='adaptive'))
    assert (margin.low, margin.high) == (1.0, 1.0)
    assert margin.text() == 'no robustness margin: unstable as declared'


def test_an_unstable_plant_model_is_named():
    """The same rig's A scaled by 1.2 (every pole 1.2 times farther out): the plant model is
    named with its largest pole modulus (numpy's eigenvalues of the scaled A), whatever the
    controller; predictor model refuses it without simulating it."""
    from seft_ros.core.force_loop import force_loop_plant
    p = _lab_loop(gain=1e-4, scale_a=1.2)
    pole = float(np.max(np.abs(np.linalg.eigvals(
        1.2 * force_loop_plant(_lab_loop()).a))))
    assert pole > 1.1
    expected = ('parameter plant_model: the force loop alone (alpha = 0, no mass fed back) is '
                'predicted unstable on the state_space rig because its plant model (lab test '
                f'model) is unstable itself (a pole at |z| = {pole:.4g}, outside the unit '
                'circle); a model of an actuator is stable: identify it again or correct the '
                'model')
    check = st.check_run(p)
    assert check.stable is False and check.message == expected
    _model_refuses(p, expected)


def test_loop_radius_is_the_loop_models_at_alpha_zero():
    """PlantModel.loop_radius of a stable and an unstable lab loop equals the spectral
    radius of the guard's LoopModel at alpha = 0 and python-control's closed-loop poles."""
    from seft_ros.core.force_loop import force_loop_plant
    for gain in (1e-3, 0.05):
        p = _lab_loop(gain=gain)
        mine = force_loop_plant(p).loop_radius(ForceServoController.from_parameters(p))
        q = dict(p, alpha=0.0)
        guard = float(st.LoopModel(q, st.compensator(q)).radii(0.0)[0])
        assert mine == pytest.approx(guard, rel=1e-9)
        assert mine == pytest.approx(_closed_radius(p), rel=1e-6)


class _CalibratedLoop:
    """A loop whose compensator depends on alpha (a pole-calibrated law) with the spectral
    radius 0.5 + alpha / 4 (stable below alpha 2), and whose law's calibration refuses the
    alphas in `refused` (``ParameterError``, as ``law_calibration.pole_calibration``)."""

    def __init__(self, refused):
        self.compensator = type('Compensator', (), {'alpha_dependent': True})()
        self.refused = refused
        self.asked = []

    def radii(self, alphas):
        alphas = np.atleast_1d(np.asarray(alphas, dtype=float))
        self.asked.extend(alphas.tolist())
        if any(lo <= a <= hi for a in alphas for lo, hi in self.refused):
            raise ParameterError("predictor_calibration poles: the loop's model reaches the "
                                 "reference structure's pole only with the law's gains offset")
        return 0.5 + 0.25 * alphas


def test_a_scan_alpha_the_calibration_refuses_counts_as_no_stable_test():
    """Session 32's lab plant 15 (a 46 Hz specimen on a 47 Hz valve): its test at alpha 1 was
    refused before it ran because the pre-run guard's scan for the largest stable alpha asked
    the pole calibration at alpha 0.25, which refused that alpha (its reference pole at 41 Hz)
    -- not the run's. A scan's alpha whose law cannot be built is now no stable test there:
    the boundary is the last alpha before it, and the intervals go on after it."""
    loop = _CalibratedLoop(refused=[(0.2, 0.3)])
    first, intervals = st._scan(loop, 3.0, 0.25, 5e-3)
    assert 0.0 < first <= 0.25 and intervals[0] == (0.0, first)
    assert len(intervals) == 2 and 0.25 <= intervals[1][0] <= 0.3 + 5e-3
    assert intervals[1][1] == pytest.approx(2.0, abs=5e-3)
    assert 0.25 in loop.asked                       # asked, refused, and taken as unstable
    # a loop whose law does not depend on alpha is scanned as before (no refusal possible)
    assert st._scan(_CalibratedLoop(refused=[]), 3.0, 0.25, 5e-3)[0] == pytest.approx(
        2.0, abs=5e-3)


def test_a_spectral_radius_is_told_from_1():
    """A radius of 1.00004 read '1' in a refusal, which does not read as unstable (a new
    user, session 36): as many figures as tell it from 1."""
    assert st.radius_text(1.00004) == '1.00004'
    assert st.radius_text(1.0000000002) == '1.0000000002'
    assert st.radius_text(0.9957123) == '0.9957' and st.radius_text(1.0304446) == '1.03'
    assert st.radius_text(1.0) == '1'
