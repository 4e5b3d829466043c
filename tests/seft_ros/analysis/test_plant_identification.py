"""The force loop's plant identified as data, its order chosen by the data
(seft_ros.analysis.plant_identification), and the controller designed for it.

The records are open-loop identification runs of actuators seft's models were not written
for (seft_plant_sim.actuator), simulated in process; the reference is each actuator
linearized at rest and sampled exactly (``ActuatorSpec.linear_plant``), which the
identification never sees.
"""

import dataclasses
import math
import re

import numpy as np
import pytest

from seft_msgs_py.errors import InputError, ParameterError
from seft_msgs_py.parameters import resolve
from seft_msgs_py.plant import Specimen
from seft_plant_sim.actuator import actuator_spec
from seft_plant_sim.specimen import LinearSpecimen
from seft_ros.analysis.plant_identification import identify_plant
from seft_ros.core.experiment import simulate

DT = 0.002
M, K = 29.13, 1.19e6
C = 0.02 * math.sqrt(K * M)


def open_loop(member, seconds=10.0, **extra):
    p = resolve(dict(mass_kg=M, stiffness_N_per_m=K, damping_N_s_per_m=C, rig_model='actuator',
                     actuator_family=member, excitation='noise',
                     excitation_input='valve_command', duration_s=seconds, **extra))
    run = simulate(p)
    rig = run.rigs['']
    y = np.column_stack([rig.measured_force_N, rig.displacement_m, rig.velocity_m_s,
                         rig.acceleration_m_s2])
    return p, rig.valve_command_V, y


@pytest.fixture(scope='module')
def second_order():
    return open_loop('valve_2nd_order')


@pytest.fixture(scope='module')
def second_order_fit(second_order):
    _, u, y = second_order
    return identify_plant(u, y, DT, specimen=Specimen(M, C, K), source='test')


def test_a_linear_actuator_is_found_exactly_at_the_order_the_data_choose(second_order,
                                                                        second_order_fit):
    """Five states (valve 2, oil column 1, specimen 2) and a 1.5-step delay: a command reaches
    the samples two steps later and the delay's fraction takes one more numerator coefficient,
    so order 5 after 2 steps is exact. The delay scan takes one step less than the longest
    the data allow (a delay too long cannot be fitted, one too short costs an order), so the
    BIC finds order 6 after 1 step, its sixth pole at z = 0 standing for the step; the model
    is the actuator's to 1e-6."""
    p, fit = second_order[0], second_order_fit
    true = actuator_spec(p).linear_plant(LinearSpecimen(M, C, K), DT)
    f = np.array([0.5, 2.0, 10.0, 32.0, 68.0, 150.0])
    for out in ('force_N', 'displacement_m', 'acceleration_m_s2'):
        ratio = fit.model.frequency_response(f, out) / true.frequency_response(f, out)
        assert np.max(np.abs(ratio - 1.0)) < 1e-6, out
    assert fit.order + fit.delay_steps == 7 and fit.delay_steps >= 1
    bics = [o['bic'] for o in fit.orders]
    assert fit.orders[int(np.argmin(bics))]['order'] == fit.order
    poles = np.sort(np.abs(np.roots(fit.a)))
    assert np.all(poles[:fit.order - 5] < 1e-4)    # the extra poles are the delay's steps
    assert fit.nrms['force_N'] < 1e-8
    assert fit.model.specimen == Specimen(M, C, K)


def test_sensor_noise_leaves_the_model_accurate_where_the_loop_is_closed():
    """With the load cell, displacement, velocity and accelerometer noise of
    benchmarks/robust_compensation.py, 10 s of noise on a three-stage valve: the force
    response within 1 % of its peak from 1 to 40 Hz (relative to its own level it cannot be
    near the specimen's zero, where the force is the noise), the control-structure
    interaction zero within 2 % of the specimen's frequency, and a controller designed from
    the model alone meets its margins on the true actuator."""
    from seft_ros.core.force_design import _Discrete, design_force_controller, plant_margins
    p, u, y = open_loop('valve_3_stage', seconds=10.0, noise_force_N=5.0,
                        noise_displacement_m=1e-5, noise_velocity_m_s=1e-4,
                        noise_acceleration_m_s2=0.05)
    fit = identify_plant(u, y, DT, specimen=Specimen(M, C, K))
    true = actuator_spec(p).linear_plant(LinearSpecimen(M, C, K), DT)
    f = np.linspace(1.0, 40.0, 79)
    h = true.frequency_response(f)
    assert np.max(np.abs(fit.model.frequency_response(f) - h)) < 0.01 * np.max(np.abs(h))
    assert 0.0 < fit.model.uncertainty.relative < 0.1
    design = design_force_controller(fit.model)
    assert design.met
    assert design.structure['specimen_hz'] == pytest.approx(Specimen(M, C, K)
                                                            .natural_frequency_hz, rel=0.02)
    m = plant_margins(true, _Discrete(np.array(design.num_z), np.array(design.den_z), DT))
    assert m.crossover_hz >= 10.0 and m.phase_margin_deg >= 45.0 and m.gain_margin >= 2.0


def test_a_record_without_excitation_or_too_short_is_refused_in_one_line(second_order):
    _, u, y = second_order
    with pytest.raises(InputError, match=r'^rec: the valve command or an output does not move'):
        identify_plant(np.zeros_like(u), y, DT, source='rec')
    with pytest.raises(InputError, match=r'^rec: 300 samples; expected at least'):
        identify_plant(u[:300], y[:300], DT, source='rec')
    with pytest.raises(ParameterError, match=r"^plant fit: the force from the specimen needs "
                                             r"the model's specimen"):
        identify_plant(u[:2000], y[:2000], DT, max_order=2).with_specimen_force(u, y)


def test_the_controller_designed_from_the_data_meets_its_margins_on_the_true_plant(
        second_order, second_order_lab):
    """Designed from the identified model alone (``seft identify``'s design of the same 10 s
    record); read on the true actuator: a crossover of 10 Hz or more, 45 deg and a gain
    margin of 2 (issue 38, target 2). The margins are checked against python-control's
    stability_margins of the same loop (an independent routine)."""
    import control

    from seft_ros.core.force_design import _Discrete, plant_margins
    p, design = second_order[0], second_order_lab[0].design
    assert design.met
    # the compensated test's gain margin falls short (session 25): the 32 Hz, 0.5 % column's
    # test is stable up to a plant gain of 1.01-1.03 x the model's, a warning says so
    assert design.gain_robust is False
    assert max(m.high for m in design.test_margin.values()) < 1.05
    assert [w[:60] for w in design.warnings] == [
        "the study's test with `model` on this design is stable for a"]
    true = actuator_spec(p).linear_plant(LinearSpecimen(M, C, K), DT)
    m = plant_margins(true, _Discrete(np.array(design.num_z), np.array(design.den_z), DT))
    assert m.crossover_hz >= 10.0 and m.phase_margin_deg >= 45.0 and m.gain_margin >= 2.0
    assert m.crossovers == 1
    loop = (control.tf(list(design.num_z), list(design.den_z), DT)
            * control.ss2tf(true.to_lti()[0, 0]))
    gm, pm, _, wpc, wgc = control.stability_margins(loop)[:5]
    assert wgc / (2 * math.pi) == pytest.approx(m.crossover_hz, rel=1e-3)
    assert pm == pytest.approx(m.phase_margin_deg, abs=0.1)
    assert gm == pytest.approx(m.gain_margin, rel=1e-3)


def lab_settings(member, specimen=(M, C, K), **extra):
    """``seft identify``'s parameter file of a 10 s open-loop run of `member` with
    `specimen` ``(m, c, k)`` (the plant as data, the controller designed for it), as a
    mapping of parameters; `extra`: the run's other parameters (``dt``)."""
    from seft_ros.analysis.rig_identification import identified_parameters, identify_rigs
    from seft_ros.cli.config import mapping_values
    m, c, k = specimen
    p = resolve(dict(mass_kg=m, stiffness_N_per_m=k, damping_N_s_per_m=c, rig_model='actuator',
                     actuator_family=member, excitation='noise',
                     excitation_input='valve_command', duration_s=10.0, **extra))
    idents = identify_rigs(simulate(p))
    found = identified_parameters(idents)
    return idents[0], mapping_values({k: v for k, v in found.items() if not k.startswith('_')})


@pytest.fixture(scope='module')
def second_order_lab():
    """:func:`lab_settings` of the second-order valve with the 32 Hz column (the record of
    :func:`second_order`: the same 10 s of the same noise), once per module: its design
    took 15-25 s."""
    return lab_settings('valve_2nd_order')


def test_the_model_states_its_level_and_the_guard_holds_back_on_a_sticking_actuator(
        second_order, second_order_fit, second_order_lab, monkeypatch):
    """The identified model states the largest force and velocity of its record. Coulomb
    friction (1 % of the stall force) holds the piston in its seals under 0.05 V of valve
    noise (peak velocity a few mm/s): its linear model fits to a few per cent and, with the
    controller designed for it, predicts the study's test on the 32 Hz column stable; the
    test at 250 N (planned 0.19 m/s) goes unstable within a second. The guard gives no
    verdict there; on the linear second-order valve, identified at 10 times that velocity,
    the same path gets its verdict and is stable and accurate, and the guard predicts what a
    plant gain 2 % off its model costs (the runs on that actuator confirm it)."""
    from seft_ros.analysis.metrics import compare_run
    from seft_ros.core.stability import check_run
    _, _, y2 = second_order
    unc = second_order_fit.model.uncertainty
    assert unc.peak_force_N == pytest.approx(np.max(np.abs(y2[:, 0] - y2[0, 0])))
    assert unc.peak_velocity_m_s == pytest.approx(np.max(np.abs(y2[:, 2] - y2[0, 2])))
    outcomes = {}
    for member in ('coulomb_friction', 'valve_2nd_order'):
        ident, written = (second_order_lab if member == 'valve_2nd_order'
                          else lab_settings(member))
        params = resolve(dict(written, mass_kg=M, stiffness_N_per_m=K, damping_N_s_per_m=C,
                              rig_model='actuator', actuator_family=member, predictor='model',
                              alpha=1.0, duration_s=3.0, amplitude_N=250.0))
        check = check_run(params)
        run = simulate(params)
        outcomes[member] = (check.stable, run.stable, check.message,
                            ident.plant.nrms['force_N'],
                            ident.plant.model.uncertainty.peak_velocity_m_s)
        if run.stable:
            assert compare_run(run).displacement.nrms < 0.01
    stuck = outcomes['coulomb_friction']
    assert stuck[3] < 0.05 and stuck[4] < 0.01, stuck        # a good fit at a few mm/s
    assert stuck[:2] == (None, False), stuck
    # the verdict first (before: 'the test ... is predicted stable (...); no verdict: ...')
    assert stuck[2].startswith('no verdict: the plant_model was identified at a peak '
                               'velocity'), stuck[2]
    assert '(the linear prediction alone: ' in stuck[2] and 'predicted stable' in stuck[2]
    assert outcomes['valve_2nd_order'][:2] == (True, True), outcomes['valve_2nd_order']
    # what a plant gain GAIN_ERROR off its model does, said before the run: this column's
    # test at alpha 1 is stable only to 1.01 x the model's gain (predicted), and runs on
    # the actuator with its flow gain that much off confirm it (an independent check): the
    # test that meets 1 % on its exact model goes unstable, or errs many times that
    from seft_ros.core.stability import GAIN_ERROR, robustness_margin
    margin = robustness_margin(params)
    assert margin.quantity == 'plant_gain' and margin.high < 1 + GAIN_ERROR, margin
    assert margin.gain_error_cost == math.inf
    assert "a plant gain 2 % off the model's is unstable (predicted): identify" in margin.text()
    nominal = compare_run(run).displacement.nrms
    spec = actuator_spec(params)
    for g in (1 - GAIN_ERROR, 1 + GAIN_ERROR):
        flow = spec.valve_flow_gain_m3_per_s_V * g
        monkeypatch.setattr('seft_plant_sim.actuator.actuator_spec', lambda p, f=flow: (
            dataclasses.replace(actuator_spec(p), valve_flow_gain_m3_per_s_V=f)))
        off = simulate(params)
        assert not off.stable or compare_run(off).displacement.nrms > 10 * nominal, g


def test_a_specimen_near_the_crossover_still_gets_a_10_hz_loop():
    """The 10 Hz, 0.5 % specimen on the pure-delay actuator: its control-structure-interaction
    zero sits where the loop crosses over. Designed from 10 s of data alone, read on the true
    actuator: 10 Hz or more, 45 deg and a gain margin of 2 (issue 38, target 2; before the
    detuned loops were judged by their sensitivity peak, 7.8 Hz). With the specimen 1 % stiffer
    or softer than the one cancelled, the true loop stays stable (python-control's closed-loop
    poles, an independent routine)."""
    import control

    from seft_ros.core.force_design import _Discrete, design_force_controller, plant_margins
    m, k = 40.0, 40.0 * (2 * math.pi * 10.0) ** 2
    c = 2 * 0.005 * math.sqrt(k * m)
    p = resolve(dict(mass_kg=m, stiffness_N_per_m=k, damping_N_s_per_m=c, rig_model='actuator',
                     actuator_family='pure_delay', excitation='noise',
                     excitation_input='valve_command', duration_s=10.0))
    rig = simulate(p).rigs['']
    y = np.column_stack([rig.measured_force_N, rig.displacement_m, rig.velocity_m_s,
                         rig.acceleration_m_s2])
    design = design_force_controller(identify_plant(rig.valve_command_V, y, DT,
                                                    specimen=Specimen(m, c, k)).model)
    assert design.met
    spec = actuator_spec(p)
    ctrl = _Discrete(np.array(design.num_z), np.array(design.den_z), DT)
    margins = plant_margins(spec.linear_plant(LinearSpecimen(m, c, k), DT), ctrl)
    assert margins.crossover_hz >= 10.0 and margins.phase_margin_deg >= 45.0
    assert margins.gain_margin >= 2.0 and margins.crossovers == 1
    for off in (0.99, 1.01):
        true = spec.linear_plant(LinearSpecimen(m, c, off * k), DT)
        loop = control.tf(list(design.num_z), list(design.den_z), DT) * control.ss2tf(
            true.to_lti()[0, 0])
        assert np.max(np.abs(control.feedback(loop, 1).poles())) < 1.0, off


def test_at_1_khz_the_default_excitation_band_still_identifies_the_actuator_exactly():
    """The default band's upper edge is 0.6 of the Nyquist frequency (150 Hz at 2 ms, 300 Hz
    at 1 ms): at dt = 1 ms an absolute 150 Hz left the band above it unexcited and the fit
    settled on order 10 at 0.1 %, its design closing no loop. Now the model is the
    second-order-valve actuator's to 1e-6, as at 2 ms."""
    from seft_ros.core.excitation import excitation_band_hz
    dt = 0.001
    p, u, y = open_loop('valve_2nd_order', seconds=5.0, dt=dt)
    assert excitation_band_hz(p) == (0.5, 300.0)
    assert excitation_band_hz(dict(p, dt=0.002)) == (0.5, 150.0)
    fit = identify_plant(u, y, dt, specimen=Specimen(M, C, K))
    true = actuator_spec(p).linear_plant(LinearSpecimen(M, C, K), dt)
    f = np.array([0.5, 2.0, 10.0, 32.0, 68.0, 150.0, 250.0])
    ratio = fit.model.frequency_response(f) / true.frequency_response(f)
    assert np.max(np.abs(ratio - 1.0)) < 1e-6
    assert fit.nrms['force_N'] < 1e-8


def test_adaptive_holds_the_loop_it_was_given_and_learns_the_specimen():
    """``adaptive`` on a loop given as data (the three-stage valve identified, its controller
    and inverse designed), the 10 Hz, 0.5 % specimen, its predictor model 20 % off (k 1.2
    times, m 0.8 times), alpha 1 (a reference structure damped 0.35 %): the loop's delay and
    gain are held at the inverse's ('auto'), m, c and k converge to the specimen's, and the
    test is within 1 % in every signal. Fitting the loop online instead moved its delay by
    tens of microseconds and cost 6.8 % (issue 38, target 3). The plant model's specimen
    frequency (adaptive_frequency_prior 'auto') starts the law at the m, k nearest the
    predictor's with that frequency: for k0 = 1.2 k, m0 = 0.8 m, in the unknowns normalised
    by them, ``theta_k = (2/3) theta_m`` nearest (1, 1) is (15/13, 10/13), i.e. m and k
    both 12/13 of the specimen's; without it the run errs 2.6 times as much in x."""
    from seft_ros.analysis.metrics import compare_run
    from seft_ros.core.predictors import adaptive_fits_loop
    m, k = 40.0, 40.0 * (2 * math.pi * 10.0) ** 2
    c = 2 * 0.005 * math.sqrt(k * m)
    _, written = lab_settings('valve_3_stage', (m, c, k))
    params = resolve(dict(written, mass_kg=m, stiffness_N_per_m=k, damping_N_s_per_m=c,
                          rig_model='actuator', actuator_family='valve_3_stage',
                          predictor='adaptive', alpha=1.0, duration_s=10.0, amplitude_N=115.0,
                          predictor_stiffness_N_per_m=1.2 * k, predictor_mass_kg=0.8 * m))
    assert not adaptive_fits_loop(params)
    assert adaptive_fits_loop(dict(params, adaptive_loop_fit='fit'))
    assert adaptive_fits_loop(resolve({'rig_model': 'servohydraulic',     # seft's rig model
                                       'adaptive_loop': 'model'}))   # latency declared
    # the guard of `seft simulate` takes the run: the model law it starts from is not built
    # for the prior (its pole calibration finds no offset), which the margin's note says;
    # it raised that error and refused the run (found in the fifteenth session)
    from seft_ros.core import stability
    margin = stability.check_run(params, margin=True).margin
    assert (margin.low, margin.high) == (0.5, 1.5)
    assert 'alone: not predicted, the model law is not built for it (' in margin.note
    # and says why: the declared specimen is not the plant model's (session 24: it blamed
    # the force-loop inverse, and a diverged search printed offsets of 1e16 N/m)
    assert re.search(r"the loop's model reaches the reference structure's pole \(10\.00 Hz, "
                     r"0\.42 % damped\) only with the law's gains offset by 6\.\d+e\+04 N/m, ",
                     margin.note), margin.note
    assert ('the declared specimen (32 kg, 1.895e+05 N/m, 12.25 Hz: predictor_* or the '
            "rig's) is 0.8 x the loop model's mass and 1.2 x its stiffness (40 kg, 1.579e+05 "
            'N/m, 10.00 Hz)') in margin.note
    assert 'check the force-loop inverse' not in margin.note
    run = simulate(params)
    assert run.stable
    est = {name: np.asarray(v) for name, v in run.rigs[''].estimates.items()}
    assert np.all(est['gain'] == 1.0) and np.ptp(est['tau_s']) == 0.0
    assert est['stiffness_N_per_m'][-1] == pytest.approx(k, rel=0.01)
    assert est['mass_kg'][-1] == pytest.approx(m, rel=0.01)
    from seft_ros.core.force_loop import force_loop_plant
    wn = 2 * math.pi * force_loop_plant(params).specimen.natural_frequency_hz
    assert wn == pytest.approx(2 * math.pi * 10.0, rel=1e-3)       # the identified specimen's
    assert est['stiffness_N_per_m'][0] / est['mass_kg'][0] == pytest.approx(wn ** 2, rel=2e-3)
    assert est['mass_kg'][0] == pytest.approx(12 / 13 * m, rel=2e-3)
    assert est['stiffness_N_per_m'][0] == pytest.approx(12 / 13 * k, rel=2e-3)
    cmp = compare_run(run)
    for signal in (cmp.displacement, cmp.acceleration, cmp.force):
        assert signal.nrms < 0.01
    without = simulate(dict(params, adaptive_frequency_prior='none'))
    est0 = without.rigs[''].estimates
    assert (est0['stiffness_N_per_m'][0], est0['mass_kg'][0]) == (1.2 * k, 0.8 * m)
    assert compare_run(without).displacement.nrms > 2 * cmp.displacement.nrms
    with pytest.raises(ParameterError, match=r"^parameter adaptive_loop_fit='no': expected one "
                                             r"of 'auto', 'fit', 'hold'$"):
        adaptive_fits_loop(dict(params, adaptive_loop_fit='no'))


def test_a_50_hz_specimen_sampled_at_1_khz_is_tested_within_1_percent():
    """The family's 50 Hz, 0.5 % specimen on the second-order-valve actuator through the
    lab's path at dt 1 ms (a 10 s open-loop run identified, the controller and inverse
    designed from it): the reference structure (paper Eq. 2.1) lies at 40.8 Hz at alpha 0.5
    and 35.4 Hz at 1, above the 25 Hz the instability monitor split at (healthy runs
    aborted within 2 s) and the 40 Hz the force-loop inverse was fitted to (24.8 % at alpha
    0.5). Now the split lies at twice the reference's frequency, the inverse is fitted up to
    the specimen's, and its delay is ranked by the errors predicted for the test's record
    (the default): 17 steps, where ranked for a Kanai-Tajimi ground the design kept 7 and
    erred 1.30 / 1.64 / 1.50 % at alpha 0.5 over these 4 s. `model` completes within 1 % in
    displacement (issue 38, target 3) and 2 % in acceleration and force (measured 0.37 /
    1.77 / 0.67 % at alpha 0.5, 0.38 / 0.53 / 0.60 % at 1)."""
    from seft_ros.analysis.metrics import compare_run
    from seft_ros.core.monitor import monitor_cutoff_hz
    from seft_ros.core.predictors import loop_band_hz
    m, k = 40.0, 40.0 * (2 * math.pi * 50.0) ** 2
    c = 2 * 0.005 * math.sqrt(k * m)
    ident, written = lab_settings('valve_2nd_order', (m, c, k), dt=0.001)
    assert loop_band_hz(ident.plant.model.specimen, 0.001) == pytest.approx(50.0, rel=0.01)
    assert ident.design.prediction_ground == 'record synthetic-default(seed=1)'
    for alpha in (0.5, 1.0):
        params = resolve(dict(written, mass_kg=m, stiffness_N_per_m=k, damping_N_s_per_m=c,
                              rig_model='actuator', actuator_family='valve_2nd_order',
                              dt=0.001, predictor='model', alpha=alpha, duration_s=4.0,
                              amplitude_N=300.0))
        assert monitor_cutoff_hz(params) == pytest.approx(2 * 50.0 / math.sqrt(1 + alpha))
        run = simulate(params)
        assert run.stable, run.abort_reason
        cmp = compare_run(run)
        errors = [100 * cmp.signal(s).nrms for s in ('displacement', 'acceleration', 'force')]
        assert errors[0] <= 1.0 and max(errors) <= 2.0, (alpha, errors)


def test_a_real_time_identification_reads_the_command_the_rig_applied():
    """Six of 5000 valve commands reach a real-time rig late (0.2-4 ms past their tick), as
    on a loaded host: on a 32 Hz, 0.5 % specimen each kick rings for seconds. Identified
    from the commands sent, the force fits to 0.38 %; from the commands the rig applied
    (``applied_valve_command``: the rig's timing records of the run), below 0.001 % (asserted:
    10 times better). The data are the real-time rig's own (WallClockRig, sub-stepped at
    0.1 ms)."""
    from scipy import signal

    from seft_plant_sim.realtime import WallClockRig
    from seft_ros.analysis.rig_identification import applied_valve_command
    from seft_ros.analysis.rundata import RunData
    from seft_ros.analysis.timing import NodeTiming
    dt, n = 0.002, 5000
    m = 40.0
    k = m * (2 * math.pi * 32.0) ** 2
    c = 2 * 0.005 * math.sqrt(k * m)
    p = resolve(dict(dt=dt, rig_model='actuator', actuator_family='valve_2nd_order',
                     mass_kg=m, stiffness_N_per_m=k, damping_N_s_per_m=c))
    rng = np.random.default_rng(3)
    u = 0.3 * signal.lfilter(*signal.butter(4, 80.0, fs=1 / dt), rng.standard_normal(n))
    latency = np.full(n, 0.0005)
    late = rng.choice(np.arange(500, n - 10), 6, replace=False)
    latency[late] = np.round((dt + rng.uniform(0.2e-3, 4e-3, 6)) / 1e-4) * 1e-4
    rig = WallClockRig(p)
    y = []
    for j in range(n):
        s = rig.measure()
        y.append((s.force_N, s.displacement_m, s.velocity_m_s, s.acceleration_m_s2))
        rig.arrive(j, u[j], j * dt + latency[j])
        rig.advance()
    y = np.array(y)
    steps = np.arange(n)
    nan = np.full(n, np.nan)
    run = RunData.one_rig(
        params=p, time_s=steps * dt, ground_acceleration_m_s2=np.zeros(n),
        reference_force_N=np.zeros(n), measured_force_N=y[:, 0], displacement_m=y[:, 1],
        velocity_m_s=y[:, 2], acceleration_m_s2=y[:, 3], valve_command_V=u,
        extra={'timing_data': {'rig': NodeTiming('rig', steps, nan, nan, nan,
                                                 np.zeros(n, bool), latency > dt, latency)}})
    applied, n_late = applied_valve_command(run)
    assert n_late == 6 and np.count_nonzero(applied != u) >= 6
    specimen = Specimen(m, c, k)
    sent_fit = identify_plant(u, y, dt, specimen=specimen).model.info['nrms']['force_N']
    applied_fit = identify_plant(applied, y, dt, specimen=specimen).model.info['nrms']['force_N']
    assert 0.003 < sent_fit < 0.01
    assert applied_fit < 0.1 * sent_fit
    # a lockstep run (no timing records), or commands that act on arrival: the command sent
    lockstep = dataclasses.replace(run, extra={})
    assert applied_valve_command(lockstep) == (pytest.approx(u, abs=0), 0)
    on_arrival = dataclasses.replace(run, params=dict(p, realtime_output='on_arrival'))
    assert applied_valve_command(on_arrival) == (pytest.approx(u, abs=0), 0)


def test_a_noisy_load_cell_leaves_the_force_zero_at_the_specimen():
    """A load cell with 0.1 N of noise (against 240 N RMS) on a 2 Hz, 0.5 % specimen (40 kg),
    20 s of valve noise (the lab path's): the force the specimen takes near 2 Hz is its
    damping's alone, a few newtons. The force's numerator fitted on its own put its zero at
    2.004 Hz with a damping ratio of 0.0023 and missed the true force response by up to 460 %
    at 1.9-2.1 Hz (a 10 s record), and the study's test that inverted that model erred by 20 %
    NRMS x at alpha 1. The record's halves say the specimen's force on the modelled motion is
    the better known there, and the model takes it: its zeros are the specimen fit's poles
    (within 0.1 % in frequency and 5 % in damping of the true ones here), the force response
    within 25 % at 1.9-2.1 Hz, and the force fit no worse than the noise allows."""
    from seft_ros.analysis.rig_identification import identify_rigs
    m, f_n, zeta = 40.0, 2.0, 0.005
    k = m * (2.0 * math.pi * f_n) ** 2
    c = 2.0 * zeta * math.sqrt(k * m)
    p = resolve(dict(mass_kg=m, stiffness_N_per_m=k, damping_N_s_per_m=c,
                     rig_model='actuator', actuator_family='valve_2nd_order',
                     excitation='noise', excitation_input='valve_command', duration_s=20.0,
                     noise_force_N=0.1))
    plant = identify_rigs(simulate(p))[0].plant
    assert plant.force_errors['specimen'] < 0.5 * plant.force_errors['own']
    true = actuator_spec(p).linear_plant(LinearSpecimen(m, c, k), DT)
    f = np.linspace(1.9, 2.1, 41)
    err = np.abs(plant.model.frequency_response(f) / true.frequency_response(f) - 1.0)
    assert np.max(err) < 0.25, np.max(err)
    s = np.log(np.roots(np.trim_zeros(plant.b[0], 'f')).astype(complex)) / DT
    near = s[np.abs(np.abs(s) / (2 * math.pi) - f_n) < 0.1]
    assert near.size == 2
    assert np.abs(near) / (2 * math.pi) == pytest.approx([f_n, f_n], rel=1e-3)
    assert -near.real / np.abs(near) == pytest.approx([zeta, zeta], rel=0.05)
    assert plant.nrms['force_N'] < 2.0 * plant.free_force_nrms
    assert plant.model.info['free_force_nrms'] == plant.free_force_nrms


def test_a_noise_free_record_keeps_its_own_force(second_order):
    """Without noise both forces are exact and the fit keeps its own (the noise-free lab
    path unchanged bit for bit): their errors on the record's halves below 1e-6."""
    _, u, y = second_order
    fit = identify_plant(u, y, DT, specimen=Specimen(M, C, K))
    b = fit.b.copy()
    assert fit.with_specimen_force(u, y) is False
    assert np.array_equal(fit.b, b) and fit.free_force_nrms is None
    assert max(fit.force_errors.values()) < 1e-6, fit.force_errors
