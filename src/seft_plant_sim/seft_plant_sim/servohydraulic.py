"""The servo-hydraulic rig: servo valve, oil column and I/O latency driving the specimen.

The classic linear model of a valve-controlled actuator pushing on a structure (Merritt 1967,
Ch. 5; Dyke et al. 1995; Carrion and Spencer 2007), plus the in-loop I/O latency a real digital
controller has, sampled exactly at the control period. ROS-free: the rig node and the
one-process simulator call :class:`ServoHydraulicRig` through the
:class:`~seft_msgs_py.interface.Rig` protocol, and the analysis functions below give the
sampled open- and closed-loop responses with the discrete force controller (paper Figs. 3-4) and
the stability
of the substructure EFT acceleration feedback (paper Eq. 5.3).

Model (continuous time, states ``x [m], x' [m/s], p_L [Pa], x_v [V]``)::

    tau_v x_v'          = u(t - tau_io) - x_v                         servo valve, 1st order
    Q                   = k_q x_v - K_c p_L                           linearized valve flow
    V_t/(4 beta) p_L'   = Q - A x' - C_l p_L                          oil-column compressibility
    f                   = A p_L                                       actuator force
    m x'' + c x' + k x  = f                                           specimen (paper Eq. 5.1)

so that, with ``C_h = V_t/(4 beta)`` and ``K = K_c + C_l``, the valve-to-force transfer function
without latency is (paper Fig. 3a)::

    H_fu(s) = A k_q (m s^2 + c s + k) / ((tau_v s + 1) [(C_h s + K)(m s^2 + c s + k) + A^2 s])

Its zeros are the specimen's poles (control-structure interaction, Dyke et al. 1995); its
lightly damped pole pair is the oil-column resonance near ``sqrt((k + A^2/C_h)/m)``.

References
----------
H. E. Merritt, *Hydraulic Control Systems*, Wiley, 1967, Ch. 5 (valve-controlled piston).
S. J. Dyke, B. F. Spencer Jr., P. Quast and M. K. Sain, Role of control-structure interaction
in protective system design, *J. Eng. Mech.* 121(2), 1995, 322-338.
J. E. Carrion and B. F. Spencer Jr., Model-based strategies for real-time hybrid testing,
NSEL Report 006, University of Illinois, 2007.
N. Nakata and S. Combs, Substructure Effective Force Testing, Sec. 3.2 (Eq. 3.1, Figs. 3-4),
Sec. 4 and Sec. 5 (Eqs. 5.1-5.4).
"""

from collections import deque
from dataclasses import dataclass, fields
import math
from typing import Mapping

import numpy as np
from scipy import optimize, signal

from seft_msgs_py.calibration import CALIBRATIONS, DEFAULT_CALIBRATION, valve_flow_gain_m3_per_s_V
from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import COMMAND_VALVE, Measurement
from seft_msgs_py.plant import OUTPUTS as PLANT_OUTPUTS
from seft_msgs_py.plant import LoopResponses, PlantModel
from seft_msgs_py.plant import Specimen as PlantSpecimen
from seft_msgs_py.sampling import chained_linear_map as _chained_linear_map
from seft_msgs_py.sampling import linear_map as _linear_map
from seft_msgs_py.sampling import split_delay as _split_delay
from seft_msgs_py.sampling import zoh as _zoh
from seft_plant_sim.sensors import Sensors
from seft_plant_sim.specimen import (
    BoucWenSpecimen,
    LinearSpecimen,
    SafetyLimits,
    make_specimen,
    rk4_hysteretic,
    rk4_step,
    substeps,
)

__all__ = [
    'ServoHydraulicParams', 'ServoHydraulicRig', 'SampledRig', 'LoopMargins', 'OUTPUTS',
    'ServoHydraulicPlant', 'loop_impulse_responses',
    'continuous_model', 'valve_to_force', 'sample', 'controller_frequency_response',
    'loop_frequency_response', 'closed_loop_force_response', 'equivalent_delay_s',
    'loop_margins', 'substructure_state_matrix', 'substructure_spectral_radius',
    'stability_boundary_alpha',
]

#: Output rows of :func:`continuous_model` and :class:`SampledRig`, in this order.
OUTPUTS = ('force_N', 'acceleration_m_s2', 'displacement_m', 'velocity_m_s',
           'actuator_force_N')
_FORCE, _ACCEL, _DISP, _VEL, _TRUE_FORCE = range(5)


# -- parameters -----------------------------------------------------------------------------

#: Default valve flow gain [m^3/(s V)]: the default reading of paper Eq. 3.1 (V/lbf).
_KQ_DEFAULT = CALIBRATIONS[DEFAULT_CALIBRATION].valve_flow_gain_m3_per_s_V


@dataclass(frozen=True)
class ServoHydraulicParams:
    """Actuator, servo valve and DAQ parameters of the servo-hydraulic rig (SI units).

    The defaults are a calibrated model of the reference rig (Shore Western 911D actuator,
    MTS 252 series servo valve, NI PXI controller at 500 Hz, Nakata and Combs Sec. 3.1): with
    the discrete loop-shaping controller at ``dt = 0.002 s`` they give the oil-column
    resonance at 90.2 Hz (Fig. 3a), a 13.6 Hz loop crossover with 57 deg phase margin and a
    gain margin of 2.75 (Fig. 3c: 12 Hz), a closed-loop force response within 0.915..1.047
    from 0.5 to 25 Hz (Fig. 4), an equivalent delay of 11.7 ms (Sec. 5.2: 10 ms identified)
    and a substructure EFT stability boundary at alpha = 1.317 (Sec. 4: alpha = 1.0 vibrated,
    alpha = 1.5 went unstable).

    The loop gain is integrator-like between the leakage corner (0.24 Hz) and the oil
    column, so the equivalent delay is about ``1/(2 pi f_c)``: a 12 Hz crossover would mean
    13 ms, a 10 ms delay a 16 Hz crossover; the defaults sit inside both target ranges.

    Parameters
    ----------
    piston_area_m2 : float > 0
        Effective piston area A [m^2]. 911D: 24.5 kN rated dynamic force (paper Sec. 3.1);
        at an assumed 20.7 MPa (3000 psi) supply, 24.5e3/20.7e6 = 1.18e-3 m^2 (1.83 in^2).
    oil_bulk_modulus_Pa : float > 0
        Effective bulk modulus beta of the oil column [Pa]; 1.0e9 Pa, mineral oil (1.4-1.7 GPa)
        softened by hoses and entrained air (Merritt 1967).
    actuator_volume_m3 : float > 0
        Total oil volume V_t of both chambers with the manifold and hoses [m^3]; 3.35e-4 m^3
        (swept volume 1.18e-3 m^2 x 0.152 m = 1.8e-4 m^3 plus about 1.5e-4 m^3 of lines).
        Calibrated so that the hydraulic stiffness ``4 beta A^2/V_t = 1.66e7 N/m`` puts the
        oil-column resonance at 90 Hz with the 52.7 kg specimen (paper Fig. 3a).
    valve_time_constant_s : float > 0
        Time constant tau_v of the first-order servo-valve spool dynamics [s]; 2.5 ms
        (64 Hz corner): a small-amplitude MTS 252 two-stage valve as a first-order lag, the
        valve model of Carrion and Spencer (2007).
    valve_flow_gain_m3_per_s_V : float > 0
        Linearized flow gain k_q [m^3/s per V of valve command]; calibrated: with A and the
        controller gain it sets the loop crossover (paper Fig. 3c), so it depends on the units
        Eq. 3.1 is read in (:mod:`seft_msgs_py.calibration`). Default 2.358e-4, the
        'us_customary' reading (Eq. 3.1 in V/lbf): 2.0 m/s at 10 V, 2.36e-3 m^3/s = 37 gpm at
        20.7 MPa supply, i.e. a valve rated about 22 gpm at 6.9 MPa drop, within the MTS 252
        family's flow range. The 'si' reading (Eq. 3.1 in V/N) has 5.3e-5: 0.45 m/s and
        8.4 gpm at 10 V (a 5 gpm valve). The loop calibration numbers above hold for both.
    valve_pressure_coefficient_m3_per_s_Pa : float >= 0
        Flow-pressure coefficient K_c of the valve at null [m^3/(s Pa)]; 8e-12, chosen
        (the order of magnitude of a practical valve near null, Merritt 1967). Sets, with
        C_l, the damping of the oil column (ratio 0.12) and the finite DC gain of the force
        loop (58, so ``|T(0)| = 0.983``).
    leakage_coefficient_m3_per_s_Pa : float >= 0
        Cross-port leakage C_l past the piston seals [m^3/(s Pa)]; 2e-12, chosen small
        (a fatigue-rated actuator's seals); only ``K_c + C_l`` matters in the linear model.
    io_latency_s : float >= 0
        Transport delay tau_io of the valve command [s] (any value, also fractional steps),
        assumed to lump DAQ sample-and-hold and the controller computation of one control
        period (2 ms at 500 Hz: the command computed from the samples of t_k is written at
        t_k+1), D/A conversion, the servo-valve amplifier and the anti-alias filter group
        delay (about 1 ms). 3 ms; a rig without it stays stable up to alpha = 2.54 and its
        closed-loop force response droops to 0.65 at 25 Hz, unlike paper Fig. 4.
    anti_alias_cutoff_hz : float >= 0
        Cut-off [Hz] of a second-order Butterworth low-pass on the force and acceleration
        channels (the two channels in feedback loops); 0 (default) disables it: its group
        delay is part of ``io_latency_s``.
    accelerometer_range_m_s2 : float >= 0
        Full-scale range of the accelerometer [m/s^2]: readings saturate there; 39.2 m/s^2
        (the reference rig's 4 g Omega accelerometer). 0: unlimited.

    Raises
    ------
    ParameterError
        If a value is not finite or out of its range.

    References
    ----------
    Merritt (1967), Ch. 5; Dyke et al. (1995); Carrion and Spencer (2007); Nakata and Combs,
    Sec. 3.1-3.2.
    """

    piston_area_m2: float = 1.18e-3
    oil_bulk_modulus_Pa: float = 1.0e9
    actuator_volume_m3: float = 3.35e-4
    valve_time_constant_s: float = 0.0025
    valve_flow_gain_m3_per_s_V: float = _KQ_DEFAULT
    valve_pressure_coefficient_m3_per_s_Pa: float = 8e-12
    leakage_coefficient_m3_per_s_Pa: float = 2e-12
    io_latency_s: float = 0.003
    anti_alias_cutoff_hz: float = 0.0
    accelerometer_range_m_s2: float = 39.2

    _POSITIVE = ('piston_area_m2', 'oil_bulk_modulus_Pa', 'actuator_volume_m3',
                 'valve_time_constant_s', 'valve_flow_gain_m3_per_s_V')

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            positive = f.name in self._POSITIVE
            ok = (isinstance(value, (int, float)) and not isinstance(value, bool)
                  and math.isfinite(value) and (value > 0 if positive else value >= 0))
            if not ok:
                raise ParameterError(f'parameter {f.name}={value!r}: expected float '
                                     + ('> 0' if positive else '>= 0'))

    @classmethod
    def from_parameters(cls, params: Mapping) -> 'ServoHydraulicParams':
        """Build from a flat parameter mapping; absent keys take the defaults.

        ``valve_flow_gain_m3_per_s_V`` absent or 0: that of the mapping's ``rig_calibration``
        (:func:`seft_msgs_py.calibration.valve_flow_gain_m3_per_s_V`).

        Raises
        ------
        ParameterError
            If a value is not a number or out of range.
        """
        values = {}
        for f in fields(cls):
            if f.name in params:
                value = params[f.name]
                if isinstance(value, bool) or not isinstance(value, (int, float)):
                    raise ParameterError(f'parameter {f.name}={value!r}: expected float')
                values[f.name] = float(value)
        values['valve_flow_gain_m3_per_s_V'] = float(valve_flow_gain_m3_per_s_V(params))
        return cls(**values)

    @property
    def hydraulic_capacitance_m3_per_Pa(self) -> float:
        """``C_h = V_t/(4 beta)`` [m^3/Pa] (Merritt 1967, Ch. 5)."""
        return self.actuator_volume_m3 / (4.0 * self.oil_bulk_modulus_Pa)

    @property
    def hydraulic_stiffness_N_per_m(self) -> float:
        """Oil-column stiffness ``4 beta A^2/V_t`` [N/m]."""
        return self.piston_area_m2 ** 2 / self.hydraulic_capacitance_m3_per_Pa

    @property
    def total_flow_pressure_coefficient(self) -> float:
        """``K = K_c + C_l`` [m^3/(s Pa)]."""
        return (self.valve_pressure_coefficient_m3_per_s_Pa
                + self.leakage_coefficient_m3_per_s_Pa)


# -- continuous and sampled models ----------------------------------------------------------

def continuous_model(params: ServoHydraulicParams,
                     specimen: LinearSpecimen) -> signal.StateSpace:
    """Continuous state space of the rig from the valve command at the valve [V].

    Parameters
    ----------
    params : ServoHydraulicParams
    specimen : LinearSpecimen

    Returns
    -------
    StateSpace
        States ``[x [m], x' [m/s], p_L [Pa], x_v [V]]`` followed, when the anti-alias filter
        is enabled, by ``[y_f, y_f', y_a, y_a']`` (filtered force and acceleration); one input,
        the valve command after the I/O latency [V]; outputs :data:`OUTPUTS`: measured force
        [N] and acceleration [m/s^2] (filtered if enabled), displacement [m], velocity [m/s]
        and the true actuator force ``A p_L`` [N]. No direct feedthrough.

    Notes
    -----
    See the module notes for the equations; the acceleration is
    ``(A p_L - c x' - k x)/m`` (paper Eq. 5.1). The anti-alias filter is
    ``y'' + sqrt(2) w_a y' + w_a^2 y = w_a^2 (input)`` with ``w_a = 2 pi f_a``.
    """
    m, c, k = specimen.mass_kg, specimen.damping_N_s_per_m, specimen.stiffness_N_per_m
    area = params.piston_area_m2
    ch = params.hydraulic_capacitance_m3_per_Pa
    kce = params.total_flow_pressure_coefficient
    tv = params.valve_time_constant_s
    a = np.array([[0.0, 1.0, 0.0, 0.0],
                  [-k / m, -c / m, area / m, 0.0],
                  [0.0, -area / ch, -kce / ch, params.valve_flow_gain_m3_per_s_V / ch],
                  [0.0, 0.0, 0.0, -1.0 / tv]])
    b = np.array([[0.0], [0.0], [0.0], [1.0 / tv]])
    force = np.array([0.0, 0.0, area, 0.0])
    accel = np.array([-k / m, -c / m, area / m, 0.0])
    c_out = np.array([force, accel, [1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], force])
    if params.anti_alias_cutoff_hz > 0:
        wa = 2.0 * np.pi * params.anti_alias_cutoff_hz
        filt = np.array([[0.0, 1.0], [-wa ** 2, -np.sqrt(2.0) * wa]])
        a_full = np.zeros((8, 8))
        a_full[:4, :4] = a
        a_full[4:6, 4:6] = filt
        a_full[6:8, 6:8] = filt
        a_full[5, :4] = wa ** 2 * force
        a_full[7, :4] = wa ** 2 * accel
        a = a_full
        b = np.vstack([b, np.zeros((4, 1))])
        c_out = np.hstack([c_out, np.zeros((5, 4))])
        c_out[_FORCE] = 0.0
        c_out[_FORCE, 4] = 1.0
        c_out[_ACCEL] = 0.0
        c_out[_ACCEL, 6] = 1.0
    return signal.StateSpace(a, b, c_out, np.zeros((5, 1)))


def valve_to_force(params: ServoHydraulicParams,
                   specimen: LinearSpecimen) -> signal.TransferFunction:
    """Continuous transfer function H_fu(s) from valve command [V] to actuator force [N].

    Without the I/O latency and the anti-alias filter (paper Fig. 3a).

    Returns
    -------
    TransferFunction
        ``H_fu(s) = A k_q (m s^2 + c s + k) / ((tau_v s + 1)[(C_h s + K)(m s^2 + c s + k)
        + A^2 s])`` [N/V].

    Notes
    -----
    Eliminating the flow Q and the displacement from the module equations (Merritt 1967,
    Ch. 5, with a spring-mass-damper load; Dyke et al. 1995). The numerator is the
    specimen's characteristic polynomial: the actuator cannot push at the specimen's natural
    frequency (control-structure interaction).
    """
    m, c, k = specimen.mass_kg, specimen.damping_N_s_per_m, specimen.stiffness_N_per_m
    area = params.piston_area_m2
    spec_poly = np.array([m, c, k])
    num = area * params.valve_flow_gain_m3_per_s_V * spec_poly
    den = np.polymul([params.hydraulic_capacitance_m3_per_Pa,
                      params.total_flow_pressure_coefficient], spec_poly)
    den = np.polyadd(den, [area ** 2, 0.0])
    den = np.polymul([params.valve_time_constant_s, 1.0], den)
    return signal.TransferFunction(num / den[0], den / den[0])






@dataclass(frozen=True)
class SampledRig:
    """The rig sampled exactly at ``dt`` with the held, delayed valve command.

    With ``tau_io = n dt + delta`` the valve sees ``u[k-n-1]`` over ``[t_k, t_k + delta)`` and
    ``u[k-n]`` over ``[t_k + delta, t_k+1)``, so the state propagates exactly as
    ``s[k+1] = phi s[k] + gamma_early u[k-n-1] + gamma_late u[k-n]`` and the readings are
    ``y[k] = c s[k]``.

    Attributes
    ----------
    dt : float
        Sample period [s].
    n_delay : int
        Whole steps n of the latency.
    delta_s : float
        Fractional remainder delta [s], ``0 <= delta < dt``.
    phi : ndarray, shape (ns, ns)
        ``exp(a dt)``.
    gamma_early, gamma_late : ndarray, shape (ns,)
        Input vectors of the early and late parts of the step ``[state units/V]``.
    c : ndarray, shape (5, ns)
        Output rows, :data:`OUTPUTS`.
    """

    dt: float
    n_delay: int
    delta_s: float
    phi: np.ndarray
    gamma_early: np.ndarray
    gamma_late: np.ndarray
    c: np.ndarray

    def frequency_response(self, freqs_hz, output: int = 0) -> np.ndarray:
        """Sampled response ``P(e^{j w dt})`` from the valve command to one output.

        Parameters
        ----------
        freqs_hz : array_like, shape (nf,)
            Frequencies [Hz], below the Nyquist frequency.
        output : int
            Index into :data:`OUTPUTS` (0: measured force [N/V]).

        Returns
        -------
        ndarray of complex, shape (nf,)
            ``c (zI - phi)^-1 (gamma_early z^-(n+1) + gamma_late z^-n)``.
        """
        z = np.exp(2j * np.pi * np.atleast_1d(np.asarray(freqs_hz, dtype=float)) * self.dt)
        ns = self.phi.shape[0]
        rhs = (self.gamma_early[None, :] * z[:, None] ** -(self.n_delay + 1)
               + self.gamma_late[None, :] * z[:, None] ** -self.n_delay)
        mats = z[:, None, None] * np.eye(ns)[None] - self.phi[None]
        x = np.linalg.solve(mats, rhs[..., None])[..., 0]
        return x @ self.c[output]

    def augmented(self):
        """Delay-free discrete state space with the past commands as extra states.

        Returns
        -------
        a : ndarray, shape (ns + n + 1, ns + n + 1)
        b : ndarray, shape (ns + n + 1, 1)
        c : ndarray, shape (5, ns + n + 1)
            State ``[s[k], u[k-n-1], ..., u[k-1]]``; input ``u[k]`` [V]; outputs
            :data:`OUTPUTS` at t_k.
        """
        ns, n = self.phi.shape[0], self.n_delay
        nz = ns + n + 1
        a = np.zeros((nz, nz))
        b = np.zeros((nz, 1))
        a[:ns, :ns] = self.phi
        a[:ns, ns] = self.gamma_early
        if n >= 1:
            a[:ns, ns + 1] = self.gamma_late
        else:
            b[:ns, 0] = self.gamma_late
        for i in range(n):
            a[ns + i, ns + i + 1] = 1.0
        b[nz - 1, 0] = 1.0
        c = np.hstack([self.c, np.zeros((self.c.shape[0], n + 1))])
        return a, b, c


def sample(params: ServoHydraulicParams, specimen: LinearSpecimen, dt: float) -> SampledRig:
    """Sample the rig exactly (zero-order hold, fractional I/O latency) at period `dt`.

    Parameters
    ----------
    params : ServoHydraulicParams
    specimen : LinearSpecimen
    dt : float > 0
        Control period [s].

    Returns
    -------
    SampledRig

    Raises
    ------
    ParameterError
        If ``dt <= 0``.

    Notes
    -----
    ``phi = exp(a dt)``, ``gamma_late = Gamma(dt - delta)`` and ``gamma_early =
    Phi(dt - delta) Gamma(delta)`` with ``Gamma(h) = int_0^h exp(a s) ds b``, by
    ``scipy.signal.cont2discrete(method='zoh')`` (the same split as
    :class:`~seft_plant_sim.delay_rig.DelayRig`).
    """
    if not (isinstance(dt, (int, float)) and dt > 0 and math.isfinite(dt)):
        raise ParameterError(f'parameter dt={dt!r}: expected float > 0')
    dt = float(dt)
    sys = continuous_model(params, specimen)
    n, delta = _split_delay(params.io_latency_s, dt)
    phi, _ = _zoh(sys.A, sys.B, dt)
    phi_rest, gamma_late = _zoh(sys.A, sys.B, dt - delta)
    _, gamma_early = _zoh(sys.A, sys.B, delta)
    return SampledRig(dt, n, delta, phi, (phi_rest @ gamma_early)[:, 0], gamma_late[:, 0],
                      np.array(sys.C))


# -- the rig as the force loop's plant ------------------------------------------------------

class ServoHydraulicPlant(PlantModel):
    """seft's servohydraulic rig as the force loop's plant
    (:class:`~seft_msgs_py.plant.PlantModel`), sampled exactly.

    The plant of :func:`sample` (:meth:`SampledRig.augmented`, the latency's past commands as
    states) with the outputs of :data:`seft_msgs_py.plant.OUTPUTS`. Its closed-loop responses
    are the exact ones of :func:`loop_impulse_responses` (the step average of the actuator
    force integrated with the rig, not approximated from the samples), and it can be rebuilt
    for another specimen (:meth:`with_specimen`) or I/O latency (:meth:`with_latency`), which
    a model of data cannot.

    Parameters
    ----------
    params : ServoHydraulicParams
    specimen : LinearSpecimen
    dt : float > 0
        Control period [s].
    source : str, optional
        Default: "seft's servohydraulic rig model".

    Attributes
    ----------
    params : ServoHydraulicParams
    linear_specimen : LinearSpecimen
    sampled : SampledRig
    """

    def __init__(self, params: ServoHydraulicParams, specimen: LinearSpecimen, dt: float, *,
                 source: str = "seft's servohydraulic rig model"):
        rig = sample(params, specimen, dt)
        a, b, c = rig.augmented()
        rows = [OUTPUTS.index(n) for n in PLANT_OUTPUTS]
        super().__init__(a, b, c[rows], rig.dt,
                         specimen=PlantSpecimen(specimen.mass_kg, specimen.damping_N_s_per_m,
                                                specimen.stiffness_N_per_m),
                         source=source)
        self.params = params
        self.linear_specimen = specimen
        self.sampled = rig

    def loop_responses(self, controller, n: int) -> LoopResponses:
        """The exact closed-loop responses (:func:`loop_impulse_responses`)."""
        return loop_impulse_responses(self.params, self.linear_specimen, controller, n)

    def with_specimen(self, specimen: LinearSpecimen) -> 'ServoHydraulicPlant':
        """The same rig with another specimen."""
        return ServoHydraulicPlant(self.params, specimen, self.dt, source=self.source)

    def with_latency(self, latency_s: float) -> 'ServoHydraulicPlant':
        """The same rig with another I/O latency [s]."""
        from dataclasses import replace
        return ServoHydraulicPlant(replace(self.params, io_latency_s=float(latency_s)),
                                   self.linear_specimen, self.dt, source=self.source)


def loop_impulse_responses(params: ServoHydraulicParams, specimen: LinearSpecimen,
                           controller, n: int) -> LoopResponses:
    """Impulse responses of the rig's force loop closed by a discrete controller.

    Parameters
    ----------
    params : ServoHydraulicParams
    specimen : LinearSpecimen
    controller : object with ``bz``, ``az`` and ``dt``
        The force controller's error path (its velocity path is left out).
    n : int
        Number of samples.

    Returns
    -------
    LoopResponses
        ``sampled``: the measured force ``f_m[j]`` for ``f_r = delta[j]`` [N/N];
        ``step_average``: ``(1/dt) int_{t_j}^{t_j+1} A p_L dt`` [N/N]. Linear (no valve
        saturation), from rest.

    Notes
    -----
    The continuous rig (:func:`continuous_model`) is augmented with the integral of the
    actuator force and sampled with the split I/O latency as :func:`sample`; the loop is
    closed with the measured force sample ``f_m[j]`` and the discrete controller, as in the
    one-process simulator.
    """
    dt = float(controller.dt)
    sys = continuous_model(params, specimen)
    ns = sys.A.shape[0]
    true_force = np.asarray(sys.C)[4]
    a = np.zeros((ns + 1, ns + 1))
    a[:ns, :ns] = sys.A
    a[ns, :ns] = true_force
    b = np.vstack([sys.B, [[0.0]]])
    nd, delta = _split_delay(params.io_latency_s, dt)
    phi, _ = _zoh(a, b, dt)
    phi_rest, g_late = _zoh(a, b, dt - delta)
    _, g_early = _zoh(a, b, delta)
    g_early = (phi_rest @ g_early)[:, 0]
    g_late = g_late[:, 0]
    measured_force = _linear_map(np.asarray(sys.C)[0], name='measured_force')
    advance = _linear_map(np.hstack([phi, g_early[:, None], g_late[:, None]]), name='advance',
                          unpack=True)
    bz, az = np.ravel(controller.bz), np.ravel(controller.az)
    bz, az = bz / az[0], az / az[0]
    nc = max(len(bz), len(az)) - 1
    bz = np.concatenate([bz, np.zeros(nc + 1 - len(bz))])
    az = np.concatenate([az, np.zeros(nc + 1 - len(az))])
    bz, az = bz.tolist(), az.tolist()
    zc = [0.0] * nc
    s = [0.0] * (ns + 1)
    u_hist = deque([0.0] * (nd + 1), maxlen=nd + 1)
    out = [0.0] * n                     # (Python lists: a store in an array costs more)
    sampled = [0.0] * n
    for j in range(n):
        fr = 1.0 if j == 0 else 0.0
        fm = measured_force(s)
        sampled[j] = fm
        e = fr - fm
        u = bz[0] * e + (zc[0] if nc else 0.0)
        for i in range(nc):
            nxt = zc[i + 1] if i + 1 < nc else 0.0
            zc[i] = bz[i + 1] * e - az[i + 1] * u + nxt
        early = u_hist[0]
        late = u_hist[1] if nd >= 1 else u
        w_before = s[ns]
        s = list(advance(s + [early, late]))
        u_hist.append(u)
        out[j] = (s[ns] - w_before) / dt
    return LoopResponses(np.array(sampled), np.array(out))


# -- the rig --------------------------------------------------------------------------------

class ServoHydraulicRig:
    """Servo valve + actuator + specimen, driven by the valve command [V] (Rig protocol).

    ``apply(u)`` holds ``u`` over ``[t_k, t_k+1)``; the valve sees it ``io_latency_s`` later
    (fractional delays split the step, see :class:`SampledRig`). ``measure()`` reads the
    sensors at ``t_k`` from the current state: force ``A p_L`` and acceleration
    ``(A p_L - c x' - k x)/m`` (through the anti-alias filter if enabled), then noise and the
    accelerometer range (:class:`~seft_plant_sim.sensors.Sensors`).

    A hysteretic specimen (:class:`~seft_plant_sim.specimen.BoucWenSpecimen`) has no exact
    discretization: the state ``[x, x', p_L, x_v, (filter states), z]`` of the module
    equations, with ``k x`` replaced by the Bouc-Wen restoring force ``f_s(x, z)``, is
    integrated with `rk4_substeps` classical Runge-Kutta substeps per step
    (:func:`~seft_plant_sim.specimen.rk4_hysteretic`), with the same held, delayed valve
    command (a substep boundary at ``delta``). The readings are those of the linear rig with
    the acceleration ``(A p_L - c x' - f_s)/m``. ``model`` is then the rig sampled with
    the specimen's initial stiffness (its small-amplitude behaviour). The default 20
    substeps (0.1 ms; the 90 Hz oil column needs them, not the specimen) are RK4-convergent:
    halving the substep changes a closed-loop run on the default record by less than 3e-7
    (relative), and one ``apply()`` costs about 35 us.

    Parameters
    ----------
    specimen : LinearSpecimen or BoucWenSpecimen
    dt : float > 0
        Control period [s].
    params : ServoHydraulicParams, optional
        Actuator, valve and DAQ parameters (default: the calibrated reference rig).
    sensors : Sensors, optional
        Default: noise-free with the accelerometer range of `params`.
    limits : SafetyLimits, optional
        Stroke and force limits (default: 911D, +/-76 mm, +/-24.5 kN).
    rk4_substeps : int >= 1
        Runge-Kutta substeps per control step (hysteretic specimen only).

    Raises
    ------
    ParameterError
        If ``dt <= 0`` or ``rk4_substeps < 1``.

    Notes
    -----
    A linear step is one (ns x ns+2) matrix-vector product on a preallocated work list
    ``[s, u_early, u_late]`` and the readings ``c s`` computed once per step, both as
    straight-line Python float code (:func:`~seft_msgs_py.sampling.linear_map`): measured
    0.9 us per ``apply()`` and 0.5 us per ``measure()`` on the development machine.

    The rig itself is linear; the controller's valve saturation (10 V) and the accelerometer
    range are what bound an unstable substructure EFT loop: with the defaults, alpha = 1.5
    and 2 ring at about 37 Hz with a few kN, within the stroke and force limits, so
    :meth:`limit_violation` does not stop such a run. With Eq. 3.1 in V/lbf (the default
    calibration) the accelerometer range bounds it first (alpha = 1.5: 4.5 kN at 4.2 V), so
    the valve does not saturate and only the instability monitor ends the run; with the 'si'
    reading the valve saturates and the loss-of-control interlock trips.

    References
    ----------
    Merritt (1967); Dyke et al. (1995); Carrion and Spencer (2007); Nakata and Combs,
    Sec. 3 and Eq. 5.1.
    """

    command_kind = COMMAND_VALVE

    def __init__(self, specimen: LinearSpecimen | BoucWenSpecimen, dt: float,
                 params: ServoHydraulicParams | None = None, sensors: Sensors | None = None,
                 limits: SafetyLimits | None = None, rk4_substeps: int = 20):
        self.params = params or ServoHydraulicParams()
        self.specimen = specimen
        self._hysteretic = isinstance(specimen, BoucWenSpecimen)
        linear = specimen.linearized() if self._hysteretic else specimen
        self.model = sample(self.params, linear, dt)
        self.dt = self.model.dt
        rng = self.params.accelerometer_range_m_s2
        self.sensors = sensors or Sensors(acceleration_range_m_s2=rng if rng > 0 else None)
        self.limits = limits or SafetyLimits()
        ns = self.model.phi.shape[0]
        self._ns = ns
        self._c = self.model.c
        n = self.model.n_delay
        # past commands, newest last: u[k-n-1], ..., u[k-1]
        self._history = deque([0.0] * (n + 1), maxlen=n + 1)
        self._late_from_history = n >= 1
        self.step = 0
        # linear specimen: s[k+1] = [phi, gamma_early, gamma_late] [s[k], u_early, u_late] on
        # the work list w, and the readings y = c s[k+1], compiled to Python floats in one
        # function: advance(w) -> (s[k+1], y)
        self._advance = _chained_linear_map(
            np.hstack([self.model.phi, self.model.gamma_early[:, None],
                       self.model.gamma_late[:, None]]), self._c, name='advance',
            unpack=True)
        self._w = [0.0] * (ns + 2)           # [state, u_early, u_late]
        # outputs at t_k, in the order of OUTPUTS
        self._y = _linear_map(self._c, name='read')(self._w)
        if self._hysteretic:
            if not (isinstance(rk4_substeps, int) and rk4_substeps >= 1):
                raise ParameterError(
                    f'parameter rk4_substeps={rk4_substeps!r}: expected int >= 1')
            self._substeps = substeps(self.dt, self.model.delta_s, rk4_substeps)
            self._rk4 = _hysteretic_step(self.params, specimen)
            self._s = [0.0] * (ns + 1)                    # [state, z]
            self._w = None

    @classmethod
    def from_parameters(cls, params: Mapping, *, rk4_substeps: int = 20) -> 'ServoHydraulicRig':
        """Build from the parameter schema.

        Reads ``dt``, the specimen (``specimen_model``, absent: 'linear'; ``mass_kg``,
        ``damping_N_s_per_m``, ``stiffness_N_per_m`` and the Bouc-Wen keys), ``noise_*``,
        ``noise_seed``, ``stroke_limit_m``, ``force_limit_N`` and the
        :class:`ServoHydraulicParams` keys (absent: defaults); `rk4_substeps` as in the
        constructor.
        """
        hp = ServoHydraulicParams.from_parameters(params)
        rng = hp.accelerometer_range_m_s2
        return cls(make_specimen(params), float(params['dt']), hp,
                   Sensors.from_parameters(params, rng if rng > 0 else None),
                   SafetyLimits.from_parameters(params), rk4_substeps=rk4_substeps)

    @property
    def time_s(self) -> float:
        """Time of the current sample [s]."""
        return self.step * self.dt

    @property
    def state(self) -> np.ndarray:
        """Copy of the continuous state at t_k, shape (ns,) (see :func:`continuous_model`)."""
        if self._hysteretic:
            return np.array(self._s[:self._ns])
        return np.array(self._w[:self._ns])

    @property
    def hysteretic_z(self) -> float | None:
        """Bouc-Wen variable z of the specimen at the current sample (None: linear)."""
        return self._s[-1] if self._hysteretic else None

    def outputs(self) -> np.ndarray:
        """Noise-free readings at t_k, shape (5,), in the order of :data:`OUTPUTS`."""
        if self._hysteretic:
            return self._hysteretic_outputs()
        return np.array(self._y)

    def _hysteretic_outputs(self) -> np.ndarray:
        """Readings of the hysteretic rig: the linear rows with ``k x`` replaced by f_s."""
        s = self._s
        y = self._c @ np.array(s[:self._ns])
        if self.params.anti_alias_cutoff_hz <= 0:
            sp = self.specimen
            y[_ACCEL] += (sp.stiffness_N_per_m * s[0] - sp.restoring_force(s[0], s[-1])) \
                / sp.mass_kg
        return y

    def true_force(self) -> float:
        """Actuator force ``A p_L`` on the specimen at the current sample [N]."""
        if self._hysteretic:
            return float(self.params.piston_area_m2 * self._s[2])
        return self._y[_TRUE_FORCE]

    def measure(self) -> Measurement:
        """Sensor readings at the current sample (see class notes)."""
        y = self._hysteretic_outputs().tolist() if self._hysteretic else self._y
        step = self.step
        return self.sensors.read(step, step * self.dt, y[_DISP], y[_VEL], y[_ACCEL],
                                 y[_FORCE])

    def apply(self, command: float) -> None:
        """Hold the valve command `command` [V] over the current step and advance."""
        u = float(command)
        hist = self._history
        if self._hysteretic:
            u_early = hist[0]
            u_late = hist[1] if self._late_from_history else u
            n_early, h_early, n_late, h_late = self._substeps
            s = rk4_hysteretic(self._rk4, self._s, u_early, h_early, n_early)
            self._s = rk4_hysteretic(self._rk4, s, u_late, h_late, n_late)
            hist.append(u)
            self.step += 1
            return
        w = self._w
        ns = self._ns
        w[ns] = hist[0]
        w[ns + 1] = hist[1] if self._late_from_history else u
        s, self._y = self._advance(w)
        w[:ns] = s
        hist.append(u)
        self.step += 1

    def limit_violation(self) -> str | None:
        """Stroke/force limit check on the true state at the current sample."""
        if self._hysteretic:
            return self.limits.violation(self.step * self.dt, float(self._s[0]),
                                         self.true_force())
        y = self._y
        x, f = y[_DISP], y[_TRUE_FORCE]
        limits = self.limits
        stroke, force = limits.stroke_limit_m, limits.force_limit_N
        if -stroke <= x <= stroke and -force <= f <= force:
            return None                 # inside the envelope (SafetyLimits.violation's test)
        return limits.violation(self.step * self.dt, x, f)


def _hysteretic_step(params: ServoHydraulicParams, specimen: BoucWenSpecimen):
    """One RK4 step ``(s, u, h, sgn x') -> s`` of the rig with a Bouc-Wen specimen.

    State ``[x, x', p_L, x_v]``, then the anti-alias filter states ``[y_f, y_f', y_a, y_a']``
    when enabled, then z; input: the valve command at the valve [V]. The equations of
    :func:`continuous_model` with ``k x`` replaced by ``f_s(x, z)`` and the Bouc-Wen rate of
    :meth:`~seft_plant_sim.specimen.BoucWenSpecimen.hysteretic_rate` with the direction of
    motion held (see :func:`~seft_plant_sim.specimen.rk4_hysteretic`); unrolled for speed
    without the filter.
    """
    inv_m, c, ak, bk, inv_dy, n, beta, gamma = specimen.coefficients()
    n1 = n - 1.0
    area = params.piston_area_m2
    inv_ch = 1.0 / params.hydraulic_capacitance_m3_per_Pa
    kce = params.total_flow_pressure_coefficient
    kq = params.valve_flow_gain_m3_per_s_V
    inv_tv = 1.0 / params.valve_time_constant_s
    wa = 2.0 * math.pi * params.anti_alias_cutoff_hz
    wa2, dmp = wa * wa, math.sqrt(2.0) * wa

    def zdot(v, z, bd):
        az = abs(z)
        return v * inv_dy * (1.0 - az ** n1 * (bd * z + gamma * az))

    def step(s, u, h, direction):
        bd = beta * direction
        x, v, p, q, z = s
        h2 = 0.5 * h
        a1 = (area * p - c * v - ak * x - bk * z) * inv_m
        p1, q1, z1 = (kq * q - area * v - kce * p) * inv_ch, (u - q) * inv_tv, zdot(v, z, bd)
        x2, v2, pp2, qq2, zz2 = x + h2 * v, v + h2 * a1, p + h2 * p1, q + h2 * q1, z + h2 * z1
        a2 = (area * pp2 - c * v2 - ak * x2 - bk * zz2) * inv_m
        p2, q2 = (kq * qq2 - area * v2 - kce * pp2) * inv_ch, (u - qq2) * inv_tv
        z2 = zdot(v2, zz2, bd)
        x3, v3, pp3, qq3, zz3 = x + h2 * v2, v + h2 * a2, p + h2 * p2, q + h2 * q2, z + h2 * z2
        a3 = (area * pp3 - c * v3 - ak * x3 - bk * zz3) * inv_m
        p3, q3 = (kq * qq3 - area * v3 - kce * pp3) * inv_ch, (u - qq3) * inv_tv
        z3 = zdot(v3, zz3, bd)
        x4, v4, pp4, qq4, zz4 = x + h * v3, v + h * a3, p + h * p3, q + h * q3, z + h * z3
        a4 = (area * pp4 - c * v4 - ak * x4 - bk * zz4) * inv_m
        p4, q4 = (kq * qq4 - area * v4 - kce * pp4) * inv_ch, (u - qq4) * inv_tv
        z4 = zdot(v4, zz4, bd)
        h6 = h / 6.0
        return [x + h6 * (v + 2.0 * (v2 + v3) + v4), v + h6 * (a1 + 2.0 * (a2 + a3) + a4),
                p + h6 * (p1 + 2.0 * (p2 + p3) + p4), q + h6 * (q1 + 2.0 * (q2 + q3) + q4),
                z + h6 * (z1 + 2.0 * (z2 + z3) + z4)]

    def rates_filtered(s, u, direction):
        x, v, p, q, yf, yfd, ya, yad, z = s
        force = area * p
        acc = (force - c * v - ak * x - bk * z) * inv_m
        return [v, acc, (kq * q - area * v - kce * p) * inv_ch, (u - q) * inv_tv,
                yfd, wa2 * (force - yf) - dmp * yfd, yad, wa2 * (acc - ya) - dmp * yad,
                zdot(v, z, beta * direction)]

    return rk4_step(rates_filtered) if params.anti_alias_cutoff_hz > 0 else step


# -- loop analysis with the discrete controller ---------------------------------------------

def _controller_coefficients(controller):
    """(b, a) of the controller in powers of z^-1, padded to equal length."""
    b = np.atleast_1d(np.asarray(controller.bz, dtype=float))
    a = np.atleast_1d(np.asarray(controller.az, dtype=float))
    n = max(len(a), len(b))
    b = np.concatenate([b, np.zeros(n - len(b))])
    a = np.concatenate([a, np.zeros(n - len(a))])
    return b, a


def controller_frequency_response(controller, freqs_hz) -> np.ndarray:
    """Discrete controller response ``C_f(e^{j w dt})`` [V/N].

    Parameters
    ----------
    controller : ForceServoController or object with ``bz``, ``az``, ``dt``
        Discrete controller ``sum b_i z^-i / sum a_i z^-i`` (the convention of
        ``scipy.signal.lfilter``) at period ``dt`` [s].
    freqs_hz : array_like, shape (nf,)
        Frequencies [Hz].

    Returns
    -------
    ndarray of complex, shape (nf,)
    """
    b, a = _controller_coefficients(controller)
    zinv = np.exp(-2j * np.pi * np.atleast_1d(np.asarray(freqs_hz, dtype=float))
                  * float(controller.dt))
    return np.polyval(b[::-1], zinv) / np.polyval(a[::-1], zinv)


def loop_frequency_response(params: ServoHydraulicParams, specimen: LinearSpecimen,
                            controller, freqs_hz) -> np.ndarray:
    """Sampled loop gain ``L = C_f(z) P(z)`` at ``z = e^{j w dt}`` (paper Fig. 3c).

    Parameters
    ----------
    params : ServoHydraulicParams
    specimen : LinearSpecimen
    controller : ForceServoController or object with ``bz``, ``az``, ``dt``
        The discrete force controller; its ``dt`` is the sample period [s].
    freqs_hz : array_like, shape (nf,)
        Frequencies [Hz], below the Nyquist frequency ``1/(2 dt)``.

    Returns
    -------
    ndarray of complex, shape (nf,)
        Dimensionless loop gain, from the force error through the controller, the held and
        delayed valve command and the rig to the measured force at the next samples.

    Notes
    -----
    ``P(z) = c_f (zI - Phi)^-1 (Gamma_e z^-(n+1) + Gamma_l z^-n)`` (:class:`SampledRig`),
    which includes the I/O latency, the zero-order hold and the anti-alias filter.
    """
    rig = sample(params, specimen, float(controller.dt))
    return (controller_frequency_response(controller, freqs_hz)
            * rig.frequency_response(freqs_hz, _FORCE))


def closed_loop_force_response(params: ServoHydraulicParams, specimen: LinearSpecimen,
                               controller, freqs_hz) -> np.ndarray:
    """Sampled closed-loop response ``T = L/(1 + L)``, reference to measured force (Fig. 4).

    Parameters and returns as :func:`loop_frequency_response` (dimensionless, [N/N]).
    The valve saturation of the controller is not modelled (small-signal response).
    """
    loop = loop_frequency_response(params, specimen, controller, freqs_hz)
    return loop / (1.0 + loop)


def equivalent_delay_s(params: ServoHydraulicParams, specimen: LinearSpecimen, controller,
                       band_hz=(1.0, 5.0)) -> float:
    """Equivalent time delay of the force loop: the low-frequency phase slope [s].

    Parameters
    ----------
    params, specimen, controller
        As :func:`loop_frequency_response`.
    band_hz : (float, float)
        Frequency band of the fit [Hz].

    Returns
    -------
    float
        ``-d(arg T)/d(omega)`` [s], least-squares slope of the unwrapped closed-loop phase
        over 41 points of the band; the linearized actuator delay tau of paper Eq. 5.2.
    """
    f = np.linspace(band_hz[0], band_hz[1], 41)
    phase = np.unwrap(np.angle(closed_loop_force_response(params, specimen, controller, f)))
    return float(-np.polyfit(2 * np.pi * f, phase, 1)[0])


@dataclass(frozen=True)
class LoopMargins:
    """Crossover and stability margins of the sampled force loop.

    Attributes
    ----------
    crossover_hz : float
        First frequency where ``|L|`` falls through 1 [Hz] (nan if none).
    phase_margin_deg : float
        ``180 + arg L`` at the crossover [deg], in (-180, 180].
    gain_margin : float
        Smallest ``1/|L|`` where ``arg L = -180 deg`` below Nyquist (inf if none).
    phase_crossover_hz : float
        Frequency of that gain margin [Hz] (nan if none).
    """

    crossover_hz: float
    phase_margin_deg: float
    gain_margin: float
    phase_crossover_hz: float


def loop_margins(params: ServoHydraulicParams, specimen: LinearSpecimen,
                 controller) -> LoopMargins:
    """Crossover frequency and gain/phase margins of the sampled force loop (Fig. 3c).

    Parameters
    ----------
    params, specimen, controller
        As :func:`loop_frequency_response`.

    Returns
    -------
    LoopMargins

    Notes
    -----
    Scanned on 4000 log-spaced frequencies from 0.01 Hz to 0.999 of Nyquist and refined
    with Brent's method on ``|L| - 1`` and on ``Im L`` (where ``Re L < 0``).
    """
    dt = float(controller.dt)
    rig = sample(params, specimen, dt)
    cf = controller

    def loop(f):
        return (controller_frequency_response(cf, f) * rig.frequency_response(f, _FORCE))

    f = np.logspace(-2, np.log10(0.999 / (2 * dt)), 4000)
    lg = loop(f)
    mag = np.abs(lg)
    down = np.nonzero((mag[:-1] > 1.0) & (mag[1:] <= 1.0))[0]
    if down.size:
        i = down[0]
        fc = optimize.brentq(lambda x: abs(loop(x)[0]) - 1.0, f[i], f[i + 1], xtol=1e-9)
        pm = (np.degrees(np.angle(loop(fc)[0])) + 180.0) % 360.0
        pm = pm - 360.0 if pm > 180.0 else pm
    else:
        fc, pm = float('nan'), float('nan')
    im = lg.imag
    flips = np.nonzero((np.sign(im[:-1]) != np.sign(im[1:])) & (lg.real[:-1] < 0))[0]
    gm, fp = float('inf'), float('nan')
    for i in flips:
        x = optimize.brentq(lambda v: loop(v)[0].imag, f[i], f[i + 1], xtol=1e-9)
        value = loop(x)[0]
        if value.real < 0 and 1.0 / abs(value) < gm:
            gm, fp = 1.0 / abs(value), x
    return LoopMargins(float(fc), float(pm), float(gm), float(fp))


# -- substructure EFT stability ---------------------------------------------------------------

def _substructure_builder(params, specimen, controller):
    """Return ``alpha -> state matrix`` (the sampling and the controller done once)."""
    a, b, c = sample(params, specimen, float(controller.dt)).augmented()
    bc, ac = _controller_coefficients(controller)
    a_c, b_c, c_c, d_c = signal.tf2ss(bc, ac)
    nz, nc = a.shape[0], a_c.shape[0]
    n = nz + nc + 1
    m = specimen.mass_kg
    base = np.zeros((n, n))
    base[:nz, :nz] = a
    base[nz:nz + nc, nz:nz + nc] = a_c
    base[-1, :nz] = c[_ACCEL]
    # force-error row e[k] = -alpha m a_prev - f_m[k], split into its alpha-free part
    err0 = np.zeros((1, n))
    err0[0, :nz] = -c[_FORCE]
    err1 = np.zeros((1, n))
    err1[0, -1] = -m
    u0 = np.zeros((1, n))                    # u[k] = C_c xc + D_c e
    u0[0, nz:nz + nc] = c_c[0]
    rows = np.vstack([b, np.zeros((nc + 1, 1))])
    rows_c = np.vstack([np.zeros((nz, 1)), b_c, np.zeros((1, 1))])
    fixed = base + rows @ (u0 + d_c[0, 0] * err0) + rows_c @ err0
    per_alpha = rows @ (d_c[0, 0] * err1) + rows_c @ err1

    def build(alpha):
        return fixed + float(alpha) * per_alpha

    return build


def substructure_state_matrix(params: ServoHydraulicParams, specimen: LinearSpecimen,
                              controller, alpha: float) -> np.ndarray:
    """Sampled state matrix of substructure EFT: rig + controller + acceleration feedback.

    Parameters
    ----------
    params, specimen, controller
        As :func:`loop_frequency_response`.
    alpha : float >= 0
        Mass ratio (paper Eq. 2.1).

    Returns
    -------
    ndarray, shape (nz + nc + 1, nz + nc + 1)
        State ``[rig state and past commands (SampledRig.augmented), controller state,
        a_m[k-1]]``. The loop is stable if all eigenvalues lie inside the unit circle.

    Notes
    -----
    The time loop of the one-process simulator, linear (no valve saturation, no sensor
    range), without the ground input::

        f_r[k] = -(1 + alpha) m xg''[k] - alpha m a_m[k-1]      (paper Eq. 5.3)
        u[k]   = C_f(z) (f_r[k] - f_m[k])
        z[k+1] = A z[k] + B u[k],  f_m[k] = c_f z[k],  a_m[k] = c_a z[k]

    with ``(A, B, c)`` of :meth:`SampledRig.augmented` and ``C_f`` in controllable canonical
    form (``scipy.signal.tf2ss``).
    """
    return _substructure_builder(params, specimen, controller)(alpha)


def substructure_spectral_radius(params: ServoHydraulicParams, specimen: LinearSpecimen,
                                 controller, alpha: float) -> float:
    """Largest eigenvalue modulus of :func:`substructure_state_matrix` (< 1: stable)."""
    return float(np.max(np.abs(np.linalg.eigvals(
        substructure_state_matrix(params, specimen, controller, alpha)))))


def stability_boundary_alpha(params: ServoHydraulicParams, specimen: LinearSpecimen,
                             controller, alpha_max: float = 5.0, tol: float = 1e-4) -> float:
    """Smallest mass ratio alpha at which the uncompensated substructure EFT loop is unstable.

    Parameters
    ----------
    params, specimen, controller
        As :func:`loop_frequency_response`.
    alpha_max : float > 0
        Upper end of the search.
    tol : float > 0
        Bisection tolerance on alpha.

    Returns
    -------
    float
        The boundary alpha (spectral radius 1), scanned in steps of 0.05 from 0 and refined
        by bisection; ``inf`` if the loop is stable up to `alpha_max`; 0 if already unstable
        at alpha = 0.
    """
    build = _substructure_builder(params, specimen, controller)

    def rho(alpha):
        return float(np.max(np.abs(np.linalg.eigvals(build(alpha)))))

    if rho(0.0) >= 1.0:
        return 0.0
    grid = np.arange(0.05, alpha_max + 1e-12, 0.05)
    lo = 0.0
    for hi in grid:
        if rho(hi) >= 1.0:
            while hi - lo > tol:
                mid = 0.5 * (lo + hi)
                if rho(mid) >= 1.0:
                    hi = mid
                else:
                    lo = mid
            return float(0.5 * (lo + hi))
        lo = hi
    return float('inf')
