"""Tests of the reference-force builder (paper Eqs. 2.5, 5.3) and its predictor registry."""

import math
import re

import numpy as np
import pytest

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import Measurement
from seft_msgs_py.parameters import spec
from seft_ros.core.reference_force import (
    PREDICTORS,
    NoPredictor,
    Predictor,
    ReferenceForceBuilder,
    make_predictor,
)

M = 52.7


def meas(k, acceleration):
    """A measurement of step k whose only relevant reading is the acceleration."""
    return Measurement(k, k * 0.002, 1e-3 * k, -2e-2 * k, acceleration, 100.0 * k)


def test_formula_by_hand():
    b = ReferenceForceBuilder(0.5, M, NoPredictor())
    # step 0, specimen at rest: -(1 + 0.5) * 52.7 * 2.0 = -158.1
    assert b.step(2.0, None) == pytest.approx(-158.1, rel=1e-15)
    # step 1: -(1.5) 52.7 (-1.0) - 0.5 * 52.7 * (-3.0) = 79.05 + 79.05 = 158.1
    assert b.step(-1.0, meas(0, -3.0)) == pytest.approx(158.1, rel=1e-15)
    # step 2: -(1.5) 52.7 (0.4) - 0.5 * 52.7 * 7.0 = -31.62 - 184.45 = -216.07
    assert b.step(0.4, meas(1, 7.0)) == pytest.approx(-216.07, rel=1e-14)
    assert b.commanded_N == pytest.approx([-158.1, 158.1, -216.07], rel=1e-14)


def test_alpha_zero_is_the_effective_force():
    b = ReferenceForceBuilder(0.0, M, NoPredictor())
    ag = np.random.default_rng(4).standard_normal(50)
    forces = [b.step(a, meas(k, 1e3 * (k + 1))) for k, a in enumerate(ag)]
    np.testing.assert_array_equal(forces, -M * ag)


def test_none_predictor_uses_the_previous_measurement():
    alpha = 1.3
    b = ReferenceForceBuilder(alpha, M, make_predictor({'predictor': 'none'}))
    rng = np.random.default_rng(8)
    ag, am = rng.standard_normal(200), rng.standard_normal(200) * 5.0
    got = [b.step(ag[0], None)]
    got += [b.step(ag[k], meas(k - 1, am[k - 1])) for k in range(1, 200)]
    a_hat = np.concatenate([[0.0], am[:-1]])
    np.testing.assert_allclose(got, -(1 + alpha) * M * ag - alpha * M * a_hat, rtol=1e-14,
                               atol=1e-12)
    p = NoPredictor()
    assert p.predict(None, []) == 0.0
    assert p.predict(meas(3, -4.5), [1.0, 2.0]) == -4.5


def test_predictor_registry_and_protocol(reference_params):
    assert set(PREDICTORS) == set(spec('predictor').choices) and 'none' in PREDICTORS
    p = make_predictor(reference_params)
    assert isinstance(p, NoPredictor) and isinstance(p, Predictor) and p.name == 'none'
    b = ReferenceForceBuilder.from_parameters(dict(reference_params, alpha=2))
    assert (b.alpha, b.mass_kg, b.predictor.name) == (2.0, 52.7, 'none')


def test_unknown_predictor():
    choices = ', '.join(repr(name) for name in PREDICTORS)
    assert choices.startswith("'none'")
    with pytest.raises(ParameterError, match='^' + re.escape(
            f"parameter predictor='smith': expected one of {choices}") + '$'):
        make_predictor({'predictor': 'smith'})


@pytest.mark.parametrize('alpha, mass, message', [
    (-0.1, M, r'^parameter alpha=-0\.1: expected float >= 0$'),
    (math.nan, M, r'^parameter alpha=nan: expected float >= 0$'),
    (0.5, 0.0, r'^parameter mass_kg=0\.0: expected float > 0$'),
    (0.5, -52.7, r'^parameter mass_kg=-52\.7: expected float > 0$'),
])
def test_builder_parameter_errors(alpha, mass, message):
    with pytest.raises(ParameterError, match=message):
        ReferenceForceBuilder(alpha, mass, NoPredictor())


def test_loop_latency_moves_the_modelled_delay_by_latency_minus_dt():
    """predictor_loop_latency_s = L: the predictor models tau + L - dt (real time, on arrival).

    The delay rig with tau = 10 ms whose commands act on arrival 0.7 ms after their sample is
    the lockstep rig with tau = 8.7 ms (tests/seft_plant_sim/test_realtime_rig.py), so the
    model predictor must then be the one built for 8.7 ms.
    """
    from seft_msgs_py import parameters
    from seft_ros.core.reference_force import make_predictor, with_loop_latency
    base = parameters.resolve({'rig_model': 'delay', 'predictor': 'model', 'alpha': 1.0})
    assert with_loop_latency(base) == base                       # 0: unchanged
    shifted = with_loop_latency(dict(base, predictor_loop_latency_s=0.0007))
    assert shifted['predictor_tau_s'] == pytest.approx(0.0087)
    assert make_predictor(dict(base, predictor_loop_latency_s=0.0007)).delay_s == \
        pytest.approx(make_predictor(dict(base, predictor_tau_s=0.0087)).delay_s)
    servo = parameters.resolve({'predictor': 'model', 'predictor_loop_latency_s': 0.0012})
    assert with_loop_latency(servo)['io_latency_s'] == pytest.approx(0.0022)
