"""The stability map against simulation for compensated runs on the servohydraulic rig.

The map (:mod:`seft_ros.core.stability`) judges the loop by the spectral radius rho of its
sampled closed-loop matrix. Its verdict is checked here against free responses of
:func:`seft_ros.core.experiment.simulate` (a short ground pulse, then nothing; instability
monitor, interlock and limits off), judged in the test alone: the envelope of the response
(the peak of |x| or |f_m| in each 0.2 s window) is fitted by ``exp(sigma t)`` after the first
0.4 s. A stable loop decays (sigma < 0), an unstable one grows (sigma > 0), and the dominant
eigenvalue fixes the rate: ``sigma = ln(rho) / dt``.

The pulse is tiny (1 uN peak ground force) so that even the growing responses stay far from
the valve's nonlinear range: the simulated rig then is the linear loop the map models.
"""

import math

import numpy as np
import pytest

from seft_ros.core import stability as st
from seft_ros.core.experiment import simulate

DT = 0.002
N = 1000                      # 2 s free response
WINDOW = 100                  # steps per envelope window (0.2 s: > half the slowest period)
SETTLE_S = 0.4                # fit the envelope after this (the faster modes have decayed)


@pytest.fixture(scope='module')
def free_response(reference_params, tmp_path_factory):
    """Servohydraulic rig at its default I/O latency, a 6 ms ground pulse then 2 s of
    nothing; no monitor, no interlock, no limits in reach, unlimited valve and
    accelerometer, no preview (it would command the pulse before t = 0)."""
    path = tmp_path_factory.mktemp('stability_compensated') / 'pulse.csv'
    t = np.arange(N) * DT
    ag = np.zeros_like(t)
    ag[1:4] = 1.0
    np.savetxt(path, np.c_[t, ag], delimiter=',')
    p = dict(reference_params, record=str(path), time_scale=1.0, amplitude_N=1e-6,
             monitor_threshold=0.0, saturation_abort_fraction=1.0, stroke_limit_m=1e3,
             force_limit_N=1e12, valve_limit_V=100.0, accelerometer_range_m_s2=0.0,
             ground_preview=False)
    assert p['rig_model'] == 'servohydraulic' and p['io_latency_s'] == 0.003
    assert p['dt'] == DT
    return p


def envelope_rate(x) -> float:
    """sigma [1/s]: least-squares slope of ln(max |x| per window) over the windows after
    ``SETTLE_S``."""
    x = np.abs(np.asarray(x, dtype=float))
    n = x.size // WINDOW
    peaks = x[:n * WINDOW].reshape(n, WINDOW).max(axis=1)
    t = (np.arange(n) + 0.5) * WINDOW * DT
    keep = t > SETTLE_S
    assert np.all(peaks[keep] > 0.0) and np.all(np.isfinite(peaks[keep]))
    return float(np.polyfit(t[keep], np.log(peaks[keep]), 1)[0])


def simulated_rates(params, alpha):
    """(sigma of the displacement, sigma of the measured force) [1/s] of a free response,
    and the envelope ratio (last window / first fitted window) of the displacement."""
    run = simulate(dict(params, alpha=alpha))
    assert run.stable and run.n_steps == N, run.abort_reason
    x = np.abs(run.displacement_m)
    first = int(SETTLE_S / DT)
    ratio = x[-WINDOW:].max() / x[first:first + WINDOW].max()
    return envelope_rate(run.displacement_m), envelope_rate(run.measured_force_N), ratio


def check_against_map(params, alpha):
    """The map's verdict at `alpha` against the simulated response; returns rho."""
    rho = st.spectral_radius(params, alpha)
    predicted = math.log(rho) / DT
    sigma_x, sigma_f, ratio = simulated_rates(params, alpha)
    for sigma in (sigma_x, sigma_f):
        assert sigma == pytest.approx(predicted, rel=0.1, abs=0.05), (alpha, rho)
    if rho < 1.0:
        assert sigma_x < 0.0 and ratio < 1.0
    else:
        assert sigma_x > 0.0 and ratio > 1.0
    return rho


def test_model_is_stable_over_the_whole_range_of_the_map(free_response):
    """``model`` has no boundary up to the map's alpha_max: the run at alpha_max decays, at
    the rate of the map's spectral radius."""
    p = dict(free_response, predictor='model')
    smap = st.stability_map(p, [p['io_latency_s']], ['model'])
    assert smap.delay_parameter == 'io_latency_s' and smap.notes == {}
    assert smap.boundary('model')[0] == math.inf
    assert smap.stable_intervals[0][0] == [(0.0, math.inf)]
    rho = check_against_map(p, smap.alpha_max)
    assert rho < 1.0


def test_a_model_error_that_the_map_calls_destabilising_does_so(free_response):
    """The predictor's model 30 % light: the map finds a boundary below alpha_max; the runs
    at 0.9 and 1.1 times it decay and grow, each at the rate of the map's spectral radius."""
    p = dict(free_response, predictor='model',
             predictor_mass_kg=0.7 * free_response['mass_kg'])
    boundary = st.largest_stable_alpha(p)
    assert 1.0 < boundary < 3.0
    assert check_against_map(p, 0.9 * boundary) < 1.0
    assert check_against_map(p, 1.1 * boundary) > 1.0


@pytest.mark.parametrize('order', [1, 2])
def test_polynomial_boundary_against_simulation(free_response, order):
    """``polynomial`` (orders 1 and 2): a boundary well below 1; 0.9 and 1.1 times it decay
    and grow at the map's rate."""
    p = dict(free_response, predictor='polynomial', polynomial_order=order)
    smap = st.stability_map(p, [p['io_latency_s']], ['polynomial'])
    boundary = float(smap.boundary('polynomial')[0])
    assert 0.0 < boundary < 1.0
    # the map's first boundary ends its first stable interval
    assert smap.stable_intervals[0][0][0] == (0.0, pytest.approx(boundary))
    assert check_against_map(p, 0.9 * boundary) < 1.0
    assert check_against_map(p, 1.1 * boundary) > 1.0
