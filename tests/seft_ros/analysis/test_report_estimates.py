"""The compensator's online estimates in simulate's RunData and in the report's figure."""

import pytest

from seft_msgs_py.errors import ParameterError
from seft_ros.analysis.report import plot_estimates
from seft_ros.core.experiment import simulate


def test_simulate_records_the_estimates_per_step_and_the_report_plots_them(tmp_path):
    run = simulate({'rig_model': 'delay', 'predictor': 'adaptive', 'alpha': 1.0,
                    'n_steps': 400, 'predictor_mass_kg': 55.0})
    assert set(run.estimates) == {'mass_kg', 'damping_N_s_per_m', 'stiffness_N_per_m',
                                  'tau_s', 'gain'}
    assert all(v.shape == (run.n_steps,) for v in run.estimates.values())
    assert run.estimates['mass_kg'][0] == 55.0          # the configured model at the start
    png = plot_estimates(run, tmp_path / 'estimates.png', title='t')
    assert png.stat().st_size > 10_000


def test_runs_without_estimates():
    run = simulate({'rig_model': 'delay', 'predictor': 'model', 'n_steps': 50})
    assert run.estimates is None
    with pytest.raises(ParameterError, match=r'^plot_estimates: the run has no estimates'):
        plot_estimates(run, 'unused.png')
