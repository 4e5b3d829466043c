"""The FIR force-loop inverse's fit: predictor_loop_delay_steps, _taps and _hf_weight."""

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_ros.analysis.metrics import compare_run
from seft_ros.core.experiment import simulate
from seft_ros.core.predictors import ForceLoopInverse

FINE = {'predictor_loop_delay_steps': 14, 'predictor_loop_taps': 96,
        'predictor_loop_hf_weight': 1e-4}


def _inverse(**over):
    return ForceLoopInverse.from_parameters(parameters.resolve(dict(
        {'rig_model': 'servohydraulic', 'predictor': 'model'}, **over)))


def test_a_finer_fit_follows_the_loop_closer_in_its_band():
    """max |W T - z^-d| up to 25 Hz: about 1 % with the defaults (d 10, 48 taps, mu 1e-3),
    under 0.3 % with d 14, 96 taps, mu 1e-4 (0.25 %); |W| stays small (the noise it
    passes)."""
    default, fine = _inverse(), _inverse(**FINE)
    assert 0.005 < default.band_error < 0.012
    assert fine.band_error < 0.003
    assert fine.max_gain < 3.0
    assert fine.delay_steps == 14 and fine.taps.shape == (96,)
    # the weight alone moves the fit: mu is what the parameter sets
    assert not np.allclose(_inverse(predictor_loop_hf_weight=1e-4).taps, default.taps)


@pytest.mark.parametrize('alpha', [0.0, 1.0])
def test_the_finer_fit_makes_model_closer_to_the_reference(alpha):
    """The study's test with 'model' (20 s of the embedded record): the finer fit halves the
    error (default 0.40 % at both alphas, measured)."""
    errors = {}
    for name, over in (('default', {}), ('fine', FINE)):
        run = simulate(parameters.resolve(dict({'alpha': alpha, 'predictor': 'model'}, **over)))
        errors[name] = compare_run(run).displacement.nrms
    assert errors['default'] > 0.003
    assert errors['fine'] < 0.5 * errors['default']


def test_a_repeated_fit_is_the_same_inverse_with_its_own_state():
    """The fits are kept by their exact inputs (a structure's stability check builds the same
    inverse dozens of times): a kept fit equals a new one bit for bit, each inverse filters
    with its own state and taps, and other inputs make another fit."""
    from seft_ros.core import predictors
    predictors._fit_loop_inverse.cache_clear()
    first = _inverse()
    again = _inverse()
    assert predictors._fit_loop_inverse.cache_info().hits >= 1
    predictors._fit_loop_inverse.cache_clear()
    fresh = _inverse()
    for inv in (again, fresh):
        assert np.array_equal(inv.taps, first.taps) and inv.taps is not first.taps
        assert (inv.band_error, inv.max_gain) == (first.band_error, first.max_gain)
    again.taps[0] += 1.0                          # one inverse's taps are its own
    assert _inverse().taps[0] == first.taps[0]
    # each filters from its own empty state
    assert [first.step(v) for v in (100.0, -50.0)] == [fresh.step(v) for v in (100.0, -50.0)]
    assert fresh._x[:2] == [-50.0, 100.0] and again._x[0] == 0.0
    assert not np.array_equal(_inverse(predictor_loop_delay_steps=12).taps, first.taps)


def test_an_impulse_response_of_two_dimensions_is_refused():
    with pytest.raises(ValueError, match=r'impulse_response: expected one dimension, got '
                                         r'shape \(2, 500\)'):
        ForceLoopInverse(np.zeros((2, 500)), 0.002, 10)


def test_a_state_space_rig_steps_its_rig_plant_model_and_names_it_when_it_does_not_parse():
    """``rig_plant``: ``rig_plant_model`` before ``plant_model``, its errors named as the
    parameter they are; None for another rig."""
    import json

    from seft_msgs_py.errors import ParameterError
    from seft_ros.core.force_loop import rig_plant
    one = {'form': 'transfer_function', 'num': {'force_N': [2.0]}, 'den': [1.0, 50.0],
           'specimen': {'mass_kg': 50.0, 'damping_N_s_per_m': 100.0,
                        'stiffness_N_per_m': 2e5}}
    two = dict(one, num={'force_N': [3.0]})
    params = {'rig_model': 'state_space', 'dt': 0.002, 'plant_model': json.dumps(one)}
    name, plant = rig_plant(params)
    assert name == 'plant_model'
    name, own = rig_plant(dict(params, rig_plant_model=two))        # a mapping, not text
    assert name == 'rig_plant_model'
    # static gains 2/50 and 3/50 of the force per volt
    assert own.frequency_response([0.0])[0].real == pytest.approx(
        1.5 * plant.frequency_response([0.0])[0].real)
    assert rig_plant(dict(params, rig_model='servohydraulic')) is None
    with pytest.raises(ParameterError, match=r'^parameter rig_plant_model.den'):
        rig_plant(dict(params, rig_plant_model=json.dumps(dict(one, den=[0.0, 0.0]))))
