"""The servo-hydraulic rig's static behaviour and loop numbers, derived here from its equations.

Every expected figure is computed in this file from the model's written equations (module
docstring of :mod:`seft_plant_sim.servohydraulic`; Merritt 1967, Ch. 5), typed anew with the
documented default constants, never taken from the code's own output:

- static gains in closed form: the valve-to-force gain ``A k_q/K`` (no flow at rest), the
  loop gain ``C_f(0) A k_q/K`` of paper Eq. 3.1 on it and the closed loop's ``L0/(1 + L0)``;
- the poles of the rig (valve ``-1/tau_v`` and the roots of the oil-column cubic), the CSI
  zero ``sqrt(k/m)/(2 pi)`` and the classic oil-column estimate ``sqrt((k + 4 beta A^2/V_t)/m)``;
- the sampled responses by the Poisson sum of the continuous transfer functions under the
  zero-order hold and the I/O latency (an independent route to the code's matrix
  exponentials), and the controller by the prewarped bilinear map in closed form.

They are compared with the rig stepped in time (steps, free responses, sine steady states)
and with the code's frequency-response, margin and stability analysis.
"""

from functools import lru_cache
import math

import numpy as np
import pytest
from scipy import optimize

from seft_plant_sim.servohydraulic import (
    ServoHydraulicParams,
    ServoHydraulicRig,
    closed_loop_force_response,
    continuous_model,
    controller_frequency_response,
    equivalent_delay_s,
    loop_frequency_response,
    loop_margins,
    sample,
    stability_boundary_alpha,
    substructure_spectral_radius,
    substructure_state_matrix,
    valve_to_force,
)
from seft_plant_sim.specimen import LinearSpecimen, SafetyLimits
from seft_ros.core.controller import ForceServoController

#: 1 lbf [N] by definition (0.45359237 kg x 9.80665 m/s^2): paper Eq. 3.1 is read in V/lbf.
LBF = 0.45359237 * 9.80665
DT = 0.002
#: The specimen (paper Sec. 3.1): m [kg], c = 17.14 m [N s/m], k [N/m].
M, C, K = 52.7, 17.14 * 52.7, 2.11e5
#: The documented defaults (ServoHydraulicParams docstring): piston area [m^2], bulk modulus
#: [Pa], oil volume [m^3], valve time constant [s], K_c and C_l [m^3/(s Pa)], I/O latency [s].
AREA, BETA, VT, TAU_V, KC, CL, TAU_IO = 1.18e-3, 1.0e9, 3.35e-4, 0.0025, 8e-12, 2e-12, 0.003
#: Valve flow gain of the default reading: 5.3e-5 m^3/(s V) per unit of force of Eq. 3.1.
KQ = 5.3e-5 * LBF
CH = VT / (4 * BETA)               # hydraulic capacitance V_t/(4 beta) [m^3/Pa]
KT = KC + CL                       # total flow-pressure coefficient [m^3/(s Pa)]
KH = 4 * BETA * AREA ** 2 / VT     # oil-column stiffness [N/m]
#: Paper Eq. 3.1, C_f(s) = 37/(s^2 + 17.14 s + 4002), in V/N.
CF_NUM, CF_DEN = 37.0 / LBF, (1.0, 17.14, 4002.0)


@pytest.fixture(scope='module')
def specimen():
    return LinearSpecimen(M, C, K)


@pytest.fixture(scope='module')
def params():
    """The default rig, without the accelerometer range (a linear rig)."""
    return ServoHydraulicParams(accelerometer_range_m_s2=0.0)


@pytest.fixture(scope='module')
def controller():
    return ForceServoController(DT)


# -- the model's equations, typed anew ---------------------------------------------------------

def spec_poly(s):
    """m s^2 + c s + k: the specimen's impedance from displacement to force."""
    return M * s ** 2 + C * s + K


def h_force(s, kq=KQ):
    """H_fu(s) = A k_q (m s^2 + c s + k) / ((tau_v s + 1)[(C_h s + K)(m s^2 + c s + k) + A^2 s]):
    flow balance Q = k_q x_v - K_c p = A x' + C_h p' + C_l p, f = A p, m x'' + c x' + k x = f,
    tau_v x_v' = u - x_v, eliminated for f/u [N/V]."""
    return AREA * kq * spec_poly(s) / ((TAU_V * s + 1)
                                       * ((CH * s + KT) * spec_poly(s) + AREA ** 2 * s))


def h_disp(s):
    """x/u = H_fu/(m s^2 + c s + k) [m/V]."""
    return h_force(s) / spec_poly(s)


def h_accel(s):
    """x''/u = s^2 x/u [m/s^2/V]."""
    return s ** 2 * h_disp(s)


def h_vel(s):
    """x'/u = s x/u [m/s/V]."""
    return s * h_disp(s)


def butterworth(cutoff_hz):
    """w_a^2/(s^2 + sqrt(2) w_a s + w_a^2), the anti-alias filter of the readings."""
    wa = 2 * np.pi * cutoff_hz
    return lambda s: wa ** 2 / (s ** 2 + math.sqrt(2) * wa * s + wa ** 2)


def sampled(h, f_hz, latency_s=TAU_IO, terms=200):
    """Sampled response of a continuous h(s) behind a zero-order hold and a transport delay:

    ``P(e^{j w dt}) = (1/dt) sum_m G(j(w + m w_s))``, ``G(s) = h(s) e^{-s tau} (1 - e^{-s dt})/s``
    (the sampled impulse response of G; Franklin, Powell and Workman, Digital Control, Ch. 4).
    h falls at least as 1/s^2, so the symmetric sum converges fast: at the default 3 ms
    latency (1.5 steps: the terms alternate in sign) 200 terms per side agree with 20000 to
    6e-11 up to 249.5 Hz; at other latencies 2000 terms agree with 40000 to 3e-11.
    """
    ws = 2 * np.pi / DT
    w = (2 * np.pi * np.atleast_1d(np.asarray(f_hz, dtype=float))[:, None]
         + ws * np.arange(-terms, terms + 1)[None, :])
    s = 1j * w
    return (h(s) * np.exp(-s * latency_s) * (1 - np.exp(-s * DT)) / s).sum(axis=1) / DT


def controller_z(f_hz, gain=1.0):
    """Eq. 3.1 by Tustin prewarped at its resonance w0 = sqrt(4002): ``s = K_w (z-1)/(z+1)``
    with ``K_w = w0/tan(w0 dt/2)``, which on the unit circle is ``s = j K_w tan(w dt/2)``."""
    w0 = math.sqrt(CF_DEN[2])
    s = 1j * w0 / math.tan(w0 * DT / 2) * np.tan(np.pi * np.asarray(f_hz, dtype=float) * DT)
    return gain * CF_NUM / (s ** 2 + CF_DEN[1] * s + CF_DEN[2])


def loop(f_hz):
    """Sampled loop gain L = C(z) P_f(z) [-]."""
    return controller_z(f_hz) * sampled(h_force, f_hz)


def oil_column_cubic():
    """(C_h s + K)(m s^2 + c s + k) + A^2 s, expanded: the rig's poles besides the valve's."""
    return [CH * M, CH * C + KT * M, CH * K + KT * C + AREA ** 2, KT * K]


#: Static gains in closed form. At rest x' = 0, so the valve flow balances the leakage:
#: k_q u = K p, f = A p = (A k_q/K) u; with C_f(0) = 37/4002 V/lbf the loop's static gain is
#: L0 = C_f(0) A k_q/K = 57.8 and the closed loop's T0 = L0/(1 + L0) = 0.983 (the figures of
#: the K_c docstring: "58, so |T(0)| = 0.983").
H0 = AREA * KQ / KT
L0 = CF_NUM / CF_DEN[2] * H0
T0 = L0 / (1 + L0)


def test_documented_defaults_and_derived_constants():
    p = ServoHydraulicParams()
    assert (p.piston_area_m2, p.oil_bulk_modulus_Pa, p.actuator_volume_m3,
            p.valve_time_constant_s, p.valve_pressure_coefficient_m3_per_s_Pa,
            p.leakage_coefficient_m3_per_s_Pa, p.io_latency_s, p.anti_alias_cutoff_hz,
            p.accelerometer_range_m_s2) == (AREA, BETA, VT, TAU_V, KC, CL, TAU_IO, 0.0, 39.2)
    assert p.valve_flow_gain_m3_per_s_V == pytest.approx(KQ, rel=1e-15)
    assert p.hydraulic_capacitance_m3_per_Pa == pytest.approx(CH, rel=1e-15)
    assert p.hydraulic_stiffness_N_per_m == pytest.approx(KH, rel=1e-14)
    assert p.total_flow_pressure_coefficient == pytest.approx(KT, rel=1e-15)
    assert KH == pytest.approx(1.66e7, rel=0.01)          # the docstring's 1.66e7 N/m
    assert (H0, L0, T0) == (pytest.approx(2.782e4, rel=1e-3), pytest.approx(57.82, rel=1e-3),
                            pytest.approx(0.983, abs=5e-4))


@pytest.mark.parametrize('cutoff_hz', [0.0, 0.8, 150.0])
def test_state_equations(specimen, cutoff_hz):
    """The continuous model is the module's equations written as x' = A x + B u, y = C x:
    states [x, x', p_L, x_v] (and the filters' [y_f, y_f', y_a, y_a'] when a cut-off, any
    value > 0, is set), outputs force, acceleration, displacement, velocity, true force."""
    p = ServoHydraulicParams(anti_alias_cutoff_hz=cutoff_hz)
    a = [[0, 1, 0, 0],                                   # x' = v
         [-K / M, -C / M, AREA / M, 0],                  # m v' = A p - c v - k x
         [0, -AREA / CH, -KT / CH, KQ / CH],             # C_h p' = k_q x_v - K p - A v
         [0, 0, 0, -1 / TAU_V]]                          # tau_v x_v' = u - x_v
    b = [[0], [0], [0], [1 / TAU_V]]
    force, accel = [0, 0, AREA, 0], [-K / M, -C / M, AREA / M, 0]
    c = [force, accel, [1, 0, 0, 0], [0, 1, 0, 0], force]
    if cutoff_hz:
        wa = 2 * np.pi * cutoff_hz
        d = math.sqrt(2) * wa                            # y'' = w_a^2 (in - y) - sqrt(2) w_a y'
        a = [row + [0] * 4 for row in a] + [
            [0] * 5 + [1, 0, 0],
            [wa ** 2 * v for v in force] + [-wa ** 2, -d, 0, 0],
            [0] * 7 + [1],
            [wa ** 2 * v for v in accel] + [0, 0, -wa ** 2, -d]]
        b += [[0]] * 4
        c = [[0] * 4 + [1, 0, 0, 0], [0] * 6 + [1, 0]] + [row + [0] * 4 for row in c[2:]]
    sys = continuous_model(p, specimen)
    for got, want in ((sys.A, a), (sys.B, b), (sys.C, c), (sys.D, np.zeros((5, 1)))):
        np.testing.assert_allclose(got, np.array(want, dtype=float), rtol=1e-13, atol=0)


# -- static (DC) behaviour -----------------------------------------------------------------------

def test_open_loop_static_gain(params, specimen):
    """A constant valve command u: the force settles at (A k_q/K) u, the pressure at k_q u/K,
    the displacement at f/k, the spool at u; the approach is the slow leakage pole s_1 (the
    real root of the oil-column cubic, about -1.5/s, 0.24 Hz). Checked on the closed-form
    transfer function, the sampled response at 1e-7 Hz and the rig stepped for 14 s."""
    tf = valve_to_force(params, specimen)
    assert tf.num[-1] / tf.den[-1] == pytest.approx(H0, rel=1e-12)
    assert sample(params, specimen, DT).frequency_response([1e-7], 0)[0] == pytest.approx(
        H0, rel=1e-5)
    u = 0.1                                        # 2.8 kN, 13 mm: inside the limits
    rig = ServoHydraulicRig(specimen, DT, params)
    forces = []
    for _ in range(7000):
        forces.append(rig.measure().force_N)
        rig.apply(u)
    f_inf = H0 * u
    x, v, p, xv = rig.state
    assert forces[-1] == pytest.approx(f_inf, rel=1e-7)
    assert p == pytest.approx(KQ * u / KT, rel=1e-7)
    assert x == pytest.approx(f_inf / K, rel=1e-7)
    assert xv == pytest.approx(u, rel=1e-12)
    assert abs(v) < 1e-7 * f_inf / K
    out = rig.outputs()
    assert out[0] == out[4] == pytest.approx(f_inf, rel=1e-7)
    assert abs(out[1]) < 1e-6 * f_inf / M
    # the decay rate of f_inf - f(t) from 2 s to 6 s (the oil column and the valve have died
    # out: e^{-68 x 2} and e^{-400 x 2}) is the slow root of the cubic
    s1 = max(np.roots(oil_column_cubic()), key=lambda r: r.real).real
    # first-order estimate: quasi-static f = k x, so (A/k + C_h/A) f' = k_q u - K f/A
    assert s1 == pytest.approx(-KT * K / (AREA ** 2 + CH * K + KT * C), rel=2e-3)
    k = np.arange(1000, 3000)
    slope = np.polyfit(k * DT, np.log(f_inf - np.array(forces)[k]), 1)[0]
    assert slope == pytest.approx(s1, rel=1e-6)


def test_closed_loop_static_gain(params, specimen, controller):
    """The force loop of paper Eq. 3.1 has no integrator: a constant reference settles at
    T0 = L0/(1 + L0) of itself with the valve at C_f(0) (f_r - f_m). Checked on the analysis
    (1e-7 Hz) and on the loop stepped in time (500 N step)."""
    assert controller_frequency_response(controller, [0.0])[0] == pytest.approx(
        CF_NUM / CF_DEN[2], rel=1e-12)             # Tustin keeps the static gain (z = 1)
    lg = loop_frequency_response(params, specimen, controller, [1e-7])[0]
    assert lg.real == pytest.approx(L0, rel=1e-6) and abs(lg.imag) < 1e-4
    tc = closed_loop_force_response(params, specimen, controller, [1e-7])[0]
    assert tc.real == pytest.approx(T0, rel=1e-7)
    ctrl = ForceServoController(DT)
    rig = ServoHydraulicRig(specimen, DT, params)
    ref = 500.0
    for _ in range(2000):                          # the closed loop's slowest pole: ~90/s
        fm = rig.measure().force_N
        u = ctrl.step(ref, fm)
        rig.apply(u)
    assert fm == pytest.approx(T0 * ref, rel=1e-9)
    assert u == pytest.approx(CF_NUM / CF_DEN[2] * ref / (1 + L0), rel=1e-9)
    assert rig.state[0] == pytest.approx(T0 * ref / K, rel=1e-9)


# -- poles, the CSI zero and the oil column ----------------------------------------------------

def test_csi_zero_and_oil_column_of_the_transfer_function(params, specimen):
    """H_fu's zeros are the specimen's poles: |s| = sqrt(k/m) = 2 pi 10.07 Hz, damping ratio
    c/(2 sqrt(k m)) = 0.135. Its poles: -1/tau_v and the cubic's roots, whose lightly damped
    pair is the oil column near sqrt((k + 4 beta A^2/V_t)/m) = 2 pi 89.96 Hz (the specimen's
    spring and the oil column both restrain the mass; the exact pair, 90.2 Hz, is shifted by
    the leakage and the damping)."""
    tf = valve_to_force(params, specimen)
    zeros = np.roots(tf.num)
    wn, zeta = math.sqrt(K / M), C / (2 * math.sqrt(K * M))
    assert wn / (2 * np.pi) == pytest.approx(10.07, abs=0.005)
    np.testing.assert_allclose(np.abs(zeros), wn, rtol=1e-9)
    np.testing.assert_allclose(-zeros.real / np.abs(zeros), zeta, rtol=1e-9)
    poles = np.sort_complex(np.roots(tf.den))
    expected = np.sort_complex(np.append(np.roots(oil_column_cubic()), -1 / TAU_V))
    np.testing.assert_allclose(poles, expected, rtol=1e-9)
    oil = expected[np.abs(expected.imag) > 0][0]
    estimate = math.sqrt((K + KH) / M)
    assert estimate / (2 * np.pi) == pytest.approx(89.96, abs=0.01)
    assert abs(oil) == pytest.approx(estimate, rel=0.005)
    assert abs(oil) / (2 * np.pi) == pytest.approx(90.2, abs=0.05)
    assert -oil.real / abs(oil) == pytest.approx(0.12, abs=0.005)
    # the static gain of the expression (s -> 0) is the flow balance's A k_q/K
    assert h_force(1e-12j).real == pytest.approx(H0, rel=1e-9)


@pytest.mark.parametrize('cutoff_hz', [0.0, 150.0])
def test_free_response_of_the_stepped_rig_is_the_model_poles(specimen, cutoff_hz):
    """After a valve pulse has passed the latency, the measured force of the stepped rig is a
    sum of the modes exp(s_i t_k) of the derived poles: the valve, the oil-column cubic and,
    when enabled, the filter's w_a (-1 +/- j)/sqrt(2). A least-squares fit on those modes
    leaves a residual at rounding level (1e-13); a pole off by 1e-7 leaves about 1e-7."""
    p = ServoHydraulicParams(accelerometer_range_m_s2=0.0, anti_alias_cutoff_hz=cutoff_hz)
    rig = ServoHydraulicRig(specimen, DT, p)
    y = []
    for k in range(320):
        y.append(rig.measure().force_N)
        rig.apply(1.0 if k < 5 else 0.0)
    # u[4] reaches the valve at t_4 + 3 ms and is held until t_5 + 3 ms < t_7
    k = np.arange(10, 320)
    y = np.array(y)[k]
    poles = list(np.roots(oil_column_cubic())) + [-1 / TAU_V]
    if cutoff_hz:
        wa = 2 * np.pi * cutoff_hz
        poles += [wa * (-1 + 1j) / math.sqrt(2)]
    basis = []
    for s in poles:
        if s.imag < 0:
            continue
        mode = np.exp(s * k * DT)
        basis += [mode.real] + ([mode.imag] if s.imag > 0 else [])
    basis = np.column_stack(basis)
    coef = np.linalg.lstsq(basis, y, rcond=None)[0]
    assert np.max(np.abs(basis @ coef - y)) < 1e-10 * np.max(np.abs(y))


def test_csi_zero_in_the_stepped_loop(params, specimen):
    """At the specimen's natural frequency the force needed is its damping force alone:
    F/X = k - m w_n^2 + j c w_n = j c w_n (the CSI zero; 90 deg lead). The loop stepped with a
    10.07 Hz reference agrees to 0.6 % (the hold's images fold back at the samples); exactly
    with the sampled ratio P_f/P_x of the Poisson sum."""
    wn = math.sqrt(K / M)
    ctrl = ForceServoController(DT)
    rig = ServoHydraulicRig(specimen, DT, params)
    n = 3000
    t = np.arange(n) * DT
    fx = np.empty((n, 2))
    for i in range(n):
        m = rig.measure()
        fx[i] = m.force_N, m.displacement_m
        rig.apply(ctrl.step(100.0 * math.sin(wn * t[i]), m.force_N))
    tail = slice(n - 1000, n)
    basis = np.column_stack([np.exp(1j * wn * t[tail]), np.exp(-1j * wn * t[tail])])
    f1, x1 = (np.linalg.lstsq(basis, fx[tail, j].astype(complex), rcond=None)[0][0]
              for j in (0, 1))
    ratio = f1 / x1
    assert ratio == pytest.approx(1j * C * wn, rel=0.006)
    assert np.degrees(np.angle(ratio)) == pytest.approx(90.0, abs=0.5)
    exact = sampled(h_force, wn / (2 * np.pi)) / sampled(h_disp, wn / (2 * np.pi))
    assert ratio == pytest.approx(exact[0], rel=1e-8)


# -- sampled responses ---------------------------------------------------------------------------

@pytest.mark.parametrize('latency_s', [0.0, 0.0013, 0.002, 0.003, 0.0047])
@pytest.mark.parametrize('cutoff_hz', [0.0, 120.0])
def test_sampled_responses_are_the_poisson_sums(specimen, latency_s, cutoff_hz):
    """Each output of SampledRig (and of its delay-free augmented form) equals the Poisson
    sum of its continuous transfer function: measured force and acceleration (through the
    filter when enabled), displacement, velocity and the true force."""
    p = ServoHydraulicParams(io_latency_s=latency_s, anti_alias_cutoff_hz=cutoff_hz)
    filt = butterworth(cutoff_hz) if cutoff_hz else (lambda s: 1.0)
    transfer = [lambda s: filt(s) * h_force(s), lambda s: filt(s) * h_accel(s), h_disp, h_vel,
                h_force]
    f = np.array([0.05, 1.0, 10.07, 37.0, 90.0, 180.0, 240.0])
    rig = sample(p, specimen, DT)
    a, b, c = rig.augmented()
    z = np.exp(2j * np.pi * f * DT)
    np.testing.assert_array_equal(rig.frequency_response(f), rig.frequency_response(f, 0))
    for out, h in enumerate(transfer):
        want = sampled(h, f, latency_s, terms=2000)
        np.testing.assert_allclose(rig.frequency_response(f, out), want, rtol=1e-9,
                                   atol=1e-12 * np.max(np.abs(want)), err_msg=str(out))
        aug = np.array([c[out] @ np.linalg.solve(zi * np.eye(a.shape[0]) - a, b[:, 0])
                        for zi in z])
        np.testing.assert_allclose(aug, want, rtol=1e-9, atol=1e-12 * np.max(np.abs(want)),
                                   err_msg=str(out))


def test_stepped_rig_impulse_response_is_the_poisson_sum(specimen, params):
    """The FFT of the stepped rig's response to one unit valve sample is P_f(e^{j w dt})."""
    n = 2 ** 14                     # 33 s: the slow pole (-1.5/s) has died out (e^-49)
    rig = ServoHydraulicRig(specimen, DT, params)
    y = np.empty(n)
    for k in range(n):
        y[k] = rig.measure().force_N
        rig.apply(1.0 if k == 0 else 0.0)
    f = np.fft.rfftfreq(n, DT)[1:-1:7]
    fft = np.fft.rfft(y)[1:-1:7]
    want = sampled(h_force, f)
    assert np.max(np.abs(fft - want)) <= 1e-9 * np.max(np.abs(want))


@pytest.mark.parametrize('latency_s, shift', [(0.004, 2), (0.003, 1), (0.0047, 2)])
def test_latency_is_a_pure_transport_delay(specimen, latency_s, shift):
    """A latency longer by `shift` whole steps gives the same readings `shift` samples later."""
    short = latency_s - shift * DT
    u = np.random.default_rng(11).standard_normal(200)
    runs = []
    for lat in (short, latency_s):
        rig = ServoHydraulicRig(specimen, DT, ServoHydraulicParams(
            io_latency_s=lat, accelerometer_range_m_s2=0.0))
        rows = []
        for uk in u:
            rows.append(rig.outputs())
            rig.apply(uk)
        runs.append(np.array(rows))
    np.testing.assert_array_equal(runs[1][:shift], 0.0)
    scale = np.max(np.abs(runs[0]), axis=0)
    assert np.all(np.max(np.abs(runs[1][shift:] - runs[0][:-shift]), axis=0) <= 1e-12 * scale)


# -- loop numbers: crossover, margins, closed loop, equivalent delay, stability boundary ----------

@lru_cache
def derived_margins(gain=1.0, differentiate=False, latency_s=TAU_IO):
    """Crossover [Hz], phase margin [deg] in (-180, 180], gain margin and phase crossover [Hz]
    of g C P (times 1 - z^-1 if `differentiate`; P with the I/O latency `latency_s`): the
    first fall of |L| through 1, 180 deg + arg L there, and the smallest 1/|L| where L
    crosses the negative real axis below Nyquist."""
    def lg(f):
        diff = 1 - np.exp(-2j * np.pi * np.asarray(f) * DT) if differentiate else 1.0
        if latency_s == TAU_IO:
            return gain * diff * loop(f)
        return gain * diff * controller_z(f) * sampled(h_force, f, latency_s, terms=2000)

    f = np.logspace(-1, math.log10(0.999 / (2 * DT)), 3000)
    scan = lg(f)
    down = np.nonzero((np.abs(scan[:-1]) > 1) & (np.abs(scan[1:]) <= 1))[0]
    fc = pm = math.nan
    if down.size:
        i = down[0]
        fc = optimize.brentq(lambda x: abs(lg(x)[0]) - 1, f[i], f[i + 1], xtol=1e-12)
        pm = 180 + np.degrees(np.angle(lg(fc)[0]))
        pm = pm - 360 if pm > 180 else pm
    gm, fp = math.inf, math.nan
    for j in np.nonzero(np.sign(scan.imag[:-1]) != np.sign(scan.imag[1:]))[0]:
        x = optimize.brentq(lambda v: lg(v)[0].imag, f[j], f[j + 1], xtol=1e-12)
        value = lg(x)[0]
        if value.real < 0 and 1 / abs(value) < gm:
            gm, fp = 1 / abs(value), x
    return fc, pm, gm, fp


def test_loop_margins_are_the_derived_ones(params, specimen, controller):
    """Crossover 13.62 Hz, phase margin 57.3 deg, gain margin 2.75 at 37.1 Hz (paper Fig. 3c:
    about 12 Hz), from the Poisson-sum loop; the code's scan agrees to its 1e-9 Hz tolerance."""
    fc, pm, gm, fp = derived_margins()
    assert 10.0 < fc < 14.0 and pm > 30.0 and gm > 2.0              # the calibration targets
    assert (fc, pm, gm, fp) == (pytest.approx(13.62, abs=0.005), pytest.approx(57.3, abs=0.05),
                                pytest.approx(2.75, abs=0.005), pytest.approx(37.1, abs=0.05))
    mg = loop_margins(params, specimen, controller)
    assert mg.crossover_hz == pytest.approx(fc, abs=1e-7)
    assert mg.phase_margin_deg == pytest.approx(pm, abs=1e-6)
    assert mg.gain_margin == pytest.approx(gm, rel=1e-8)
    assert mg.phase_crossover_hz == pytest.approx(fp, abs=1e-7)


class _Scaled:
    """Paper Eq. 3.1's discrete controller times a gain (the controller protocol: bz, az, dt)."""

    def __init__(self, gain, differentiate=False):
        base = ForceServoController(DT)
        bz = np.convolve(base.bz, [1.0, -1.0]) if differentiate else np.asarray(base.bz)
        self.bz, self.az, self.dt = gain * bz, list(base.az), DT


@pytest.mark.parametrize('gain', [4.0, 1e-3, -2.73])
def test_loop_margins_of_scaled_controllers(params, specimen, gain):
    """Gain g: above the gain margin (g = 4) the crossover moves past the phase crossover and
    the phase margin is negative (the gain margin is 2.75/g); at g = 1e-3 |L| < 1 everywhere
    (L0 = 0.058): no crossover (nan). g = -2.73 (a sign error in the loop): L is near +1 at
    its crossover, a phase margin just above -180 deg (-179.4), and its phase crossover is
    another one (89.5 Hz)."""
    fc, pm, gm, fp = derived_margins(gain)
    mg = loop_margins(params, specimen, _Scaled(gain))
    assert mg.gain_margin == pytest.approx(gm, rel=1e-8)
    assert mg.phase_crossover_hz == pytest.approx(fp, abs=1e-7)
    if gain > 0:
        _, _, gm1, fp1 = derived_margins()
        assert (gm, fp) == (pytest.approx(gm1 / gain, rel=1e-12), pytest.approx(fp1, abs=1e-9))
    if gain == 1e-3:
        assert math.isnan(fc) and math.isnan(mg.crossover_hz) and math.isnan(mg.phase_margin_deg)
        return
    assert mg.crossover_hz == pytest.approx(fc, abs=1e-7)
    assert mg.phase_margin_deg == pytest.approx(pm, abs=1e-6)
    if gain == 4.0:
        assert fc > fp and pm < 0.0
    else:
        assert -180.0 < pm < -179.0 and fp > 80.0


@pytest.mark.parametrize('gain', [100.0, 200.0])
def test_loop_margins_of_a_differentiating_controller(params, specimen, gain):
    """g (1 - z^-1) x Eq. 3.1 (numerator one longer than the denominator): |L| starts below 1
    at 0.01 Hz (g = 100: 0.73) or above (g = 200: 1.45) and falls through 1 only high up, at
    157 Hz and 173 Hz; the gain margin is at 64.3 Hz. The scan finds them over its whole
    band, up to 0.999 of Nyquist."""
    fc, pm, gm, fp = derived_margins(gain, differentiate=True)
    assert 150.0 < fc < 250.0 and fp == pytest.approx(64.3, abs=0.1)
    mg = loop_margins(params, specimen, _Scaled(gain, differentiate=True))
    assert mg.crossover_hz == pytest.approx(fc, abs=1e-7)
    assert mg.phase_margin_deg == pytest.approx(pm, abs=1e-6)
    assert mg.gain_margin == pytest.approx(gm, rel=1e-8)
    assert mg.phase_crossover_hz == pytest.approx(fp, abs=1e-7)


def test_gain_margin_is_the_smallest_over_several_phase_crossovers(specimen):
    """With a 10 ms I/O latency, 100 (1 - z^-1) x Eq. 3.1 crosses the negative real axis at
    33.9 Hz with |L| = 16.8, then at 90.8 Hz with |L| = 29.2 (and at 154 Hz with 1.02): the
    gain margin is the smallest 1/|L| of them all, 1/29.2 = 0.0342 at 90.8 Hz, not the first
    crossing's 1/16.8 (the two within a factor of 2 of each other)."""
    fc, pm, gm, fp = derived_margins(100.0, differentiate=True, latency_s=0.01)
    assert fp == pytest.approx(90.8, abs=0.05) and gm == pytest.approx(1 / 29.2, rel=1e-3)
    mg = loop_margins(ServoHydraulicParams(io_latency_s=0.01, accelerometer_range_m_s2=0.0),
                      specimen, _Scaled(100.0, differentiate=True))
    assert mg.gain_margin == pytest.approx(gm, rel=1e-8)
    assert mg.phase_crossover_hz == pytest.approx(fp, abs=1e-7)
    assert mg.crossover_hz == pytest.approx(fc, abs=1e-7)
    assert mg.phase_margin_deg == pytest.approx(pm, abs=1e-6)


def test_closed_loop_and_equivalent_delay_are_the_derived_ones(params, specimen, controller):
    """T = L/(1 + L) from the derived loop: 0.915..1.047 from 0.5 to 25 Hz (paper Fig. 4: flat),
    and the equivalent delay, the least-squares phase slope over 41 points of 1-5 Hz: 11.7 ms
    (Sec. 5.2: about 10 ms)."""
    f = np.linspace(0.5, 25.0, 491)
    lg = loop(f)
    t = lg / (1 + lg)
    np.testing.assert_allclose(closed_loop_force_response(params, specimen, controller, f), t,
                               rtol=1e-9)
    np.testing.assert_allclose(loop_frequency_response(params, specimen, controller, f), lg,
                               rtol=1e-9)
    assert 0.9 < np.abs(t).min() and np.abs(t).max() < 1.06
    assert np.abs(t[-1]) == pytest.approx(0.915, abs=5e-4)          # the droop at 25 Hz
    taus = {}
    for band in ((1.0, 5.0), (0.5, 2.0)):
        fb = np.linspace(band[0], band[1], 41)
        lb = loop(fb)
        phase = np.unwrap(np.angle(lb / (1 + lb)))
        taus[band] = -np.polyfit(2 * np.pi * fb, phase, 1)[0]
        assert equivalent_delay_s(params, specimen, controller, band) == pytest.approx(
            taus[band], rel=1e-8)
    assert taus[1.0, 5.0] == pytest.approx(0.0117, abs=5e-5)
    assert equivalent_delay_s(params, specimen, controller) == pytest.approx(taus[1.0, 5.0],
                                                                             rel=1e-8)


@pytest.mark.parametrize('freq_hz', [0.5, 2.0, 20.0])
def test_sine_steady_state_of_the_stepped_loop_is_derived_t(params, specimen, freq_hz):
    """A 100 N sine reference through the stepped loop: the measured force's fundamental is
    T(e^{j w dt}) of the derived loop (1e-7)."""
    ctrl = ForceServoController(DT)
    rig = ServoHydraulicRig(specimen, DT, params)
    n = 3000
    t = np.arange(n) * DT
    fm = np.empty(n)
    for k in range(n):
        fm[k] = rig.measure().force_N
        rig.apply(ctrl.step(100.0 * math.sin(2 * np.pi * freq_hz * t[k]), fm[k]))
    tail = slice(n - 1000, n)                          # 2 s: whole periods
    w = 2 * np.pi * freq_hz
    basis = np.column_stack([np.sin(w * t[tail]), np.cos(w * t[tail])])
    a, b = np.linalg.lstsq(basis, fm[tail], rcond=None)[0]
    lg = loop(freq_hz)[0]
    assert (a + 1j * b) / 100.0 == pytest.approx(lg / (1 + lg), rel=1e-7)


@lru_cache
def boundary_by_nyquist(gain=1.0):
    """The uncompensated substructure loop (paper Eq. 5.3) f_r = -alpha m a_m[k-1],
    u = g C (f_r - f_m): 1 + g C P_f + alpha m z^-1 g C P_a = 0. On the unit circle
    alpha(w) = -(1 + g L)/(m z^-1 g C P_a) is real and positive where a root crosses it; the
    boundary is the smallest such alpha (the loop is stable at alpha = 0: g < 2.75)."""
    def g(f):
        z = np.exp(2j * np.pi * np.atleast_1d(f) * DT)
        return ((1 + gain * loop(f))
                / (M / z * controller_z(f, gain) * sampled(h_accel, f)))

    f = np.linspace(0.1, 0.999 / (2 * DT), 4000)
    gf = g(f)
    best = (math.inf, math.nan)
    for i in np.nonzero(np.sign(gf.imag[:-1]) != np.sign(gf.imag[1:]))[0]:
        x = optimize.brentq(lambda v: g(v)[0].imag, f[i], f[i + 1], xtol=1e-12)
        value = g(x)[0]
        if value.real < 0:
            best = min(best, (-value.real, x))
    return best


def test_stability_boundary_is_the_derived_one(params, specimen, controller):
    """The boundary alpha = 1.317 at 32.6 Hz (Sec. 4: 1.0 vibrated, 1.5 went unstable), from the
    Nyquist condition on the derived loop. There the state matrix has an eigenvalue on the
    unit circle at angle 2 pi f dt; the scan-and-bisection agrees within its tolerance."""
    alpha, f = boundary_by_nyquist()
    assert 1.0 < alpha < 1.5
    big = substructure_state_matrix(params, specimen, controller, alpha)
    eig = np.linalg.eigvals(big)
    top = eig[np.argmax(np.abs(eig))]
    assert abs(top) == pytest.approx(1.0, abs=1e-9)
    assert abs(np.angle(top)) == pytest.approx(2 * np.pi * f * DT, abs=1e-8)
    for da, stable in ((-1e-3, True), (1e-3, False)):
        rho = substructure_spectral_radius(params, specimen, controller, alpha + da)
        assert (rho < 1.0) == stable
    assert stability_boundary_alpha(params, specimen, controller) == pytest.approx(
        alpha, abs=1e-4)
    assert stability_boundary_alpha(params, specimen, controller, tol=0.02) == pytest.approx(
        alpha, abs=0.02)
    assert stability_boundary_alpha(params, specimen, controller, alpha_max=1.2) == math.inf
    # 4 x Eq. 3.1 is beyond the gain margin (2.75): unstable already at alpha = 0
    assert stability_boundary_alpha(params, specimen, _Scaled(4.0)) == 0.0


@pytest.mark.parametrize('gain, low, high', [
    (2.7, 0.0, 0.05),        # near the gain margin: below the first grid point (0.05)
    (2.0, 0.05, 1.0),
    (0.33, 5.0, 6.0),        # beyond the default search range (alpha_max = 5)
])
def test_stability_boundary_of_scaled_controllers(params, specimen, gain, low, high):
    """g x Eq. 3.1: a higher gain lowers the boundary. The derived boundary is found by the
    scan and bisection wherever it lies, and reported as inf beyond alpha_max."""
    alpha, _ = boundary_by_nyquist(gain)
    assert low < alpha < high
    ctrl = _Scaled(gain)
    if high > 5.0:
        assert stability_boundary_alpha(params, specimen, ctrl) == math.inf
        # the scan includes alpha_max itself: the multiple of 0.05 just above the boundary
        top = math.ceil(alpha / 0.05) * 0.05
        for alpha_max in (6.0, top):
            assert stability_boundary_alpha(params, specimen, ctrl,
                                            alpha_max=alpha_max) == pytest.approx(alpha, abs=1e-4)
    else:
        assert stability_boundary_alpha(params, specimen, ctrl) == pytest.approx(alpha,
                                                                                 abs=1e-4)


def test_state_matrix_reproduces_the_stepped_loop_at_the_boundary(params, specimen):
    """At the derived boundary the stepped loop (unsaturated) neither grows nor decays: the
    envelope of its force is constant to 1e-3 over 4 s once the other modes have died out."""
    alpha, _ = boundary_by_nyquist()
    ctrl = ForceServoController(DT, valve_limit_V=1e9)
    rig = ServoHydraulicRig(specimen, DT, params, limits=SafetyLimits(1e9, 1e12))
    rig.apply(1.0)
    forces = []
    a_prev = 0.0
    for _ in range(3500):
        m = rig.measure()
        u = ctrl.step(-alpha * M * a_prev, m.force_N)
        a_prev = m.acceleration_m_s2
        forces.append(m.force_N)
        rig.apply(u)
    env = np.abs(np.array(forces)).reshape(-1, 250).max(axis=1)
    assert env[-1] / env[5] == pytest.approx(1.0, abs=1e-3)
