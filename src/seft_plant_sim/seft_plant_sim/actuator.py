"""A family of servo-hydraulic actuators seft's models were not designed for (``rig_model:
actuator``).

seft's own rig (:mod:`seft_plant_sim.servohydraulic`) is one actuator: a first-order valve,
a linear valve flow, no friction, a 3 ms latency. A lab's actuator is another. This module
simulates others, for the tests and the benchmark that must not design for the plant they run
on (they identify it from its bags, as a lab does, ``seft identify``), and for a lab that wants
to see what its own actuator's nonlinearities do to a test. Each member is the classic
valve-controlled actuator (Merritt 1967, Ch. 5) with one thing seft's rig has not::

    valve      first order, second order (Thayer 1965: a two-stage valve), or three stages
               (a second-order pilot driving a main-stage spool position loop)
    flow       Q = k_q x_v                               linear
               Q = k_q x_v sqrt(1 - sgn(x_v) p_L / p_s)  through an orifice (Merritt Sec. 5.2)
    oil        C_h p_L' = Q - A x' - K p_L               compressible, K = leakage + K_c
    friction   f_m = A p_L - F_c tanh(x' / v_s)          Coulomb, smoothed (Karnopp 1985)
    specimen   m x'' + c x' + k x = f_m                  the load cell between them
    delay      the valve sees u(t - tau_io)              DAQ, computation, D/A, amplifier

integrated with classical Runge-Kutta substeps (the delayed command switches on a substep
boundary, as :class:`~seft_plant_sim.servohydraulic.ServoHydraulicRig`).

:data:`FAMILY` names six members (a second-order valve, a three-stage valve, a leaky
actuator, orifice flow, Coulomb friction and a long pure delay); :func:`actuator_spec`
builds one for a specimen and draws a Monte-Carlo spread of its parameters
(``actuator_spread``, ``actuator_seed``).

References
----------
H. E. Merritt, Hydraulic Control Systems, Wiley, 1967, Ch. 5 and 7.
W. J. Thayer, Transfer functions for Moog servovalves, Moog Technical Bulletin 103, 1965.
D. Karnopp, Computer simulation of stick-slip friction in mechanical dynamic systems, J.
Dyn. Syst. Meas. Control 107(1), 1985, 100-103.
S. J. Dyke et al., Role of control-structure interaction in protective system design, J. Eng.
Mech. 121(2), 1995.
"""

from collections import deque
from dataclasses import dataclass, fields, replace
import math
from typing import Mapping

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import COMMAND_VALVE, Measurement
from seft_msgs_py.plant import PlantModel, sample_continuous
from seft_msgs_py.plant import Specimen as PlantSpecimen
from seft_msgs_py.sampling import split_delay
from seft_plant_sim.sensors import Sensors
from seft_plant_sim.specimen import LinearSpecimen, SafetyLimits, substeps

__all__ = ['ActuatorSpec', 'ActuatorRig', 'FAMILY', 'VALVES', 'actuator_spec']

#: The valve models of :class:`ActuatorSpec`.
VALVES = ('first_order', 'second_order', 'three_stage')


@dataclass(frozen=True)
class ActuatorSpec:
    """One servo-hydraulic actuator (SI units; the module notes give the equations).

    Attributes
    ----------
    name : str
    piston_area_m2 : float > 0
        A [m^2].
    oil_bulk_modulus_Pa : float > 0
        beta [Pa].
    actuator_volume_m3 : float > 0
        V_t [m^3]: ``C_h = V_t / (4 beta)``.
    valve_flow_gain_m3_per_s_V : float > 0
        k_q [m^3/(s V)].
    valve : str
        One of :data:`VALVES`.
    valve_hz : float > 0
        The corner (first order), natural frequency (second order) or the pilot's natural
        frequency (three stages) [Hz].
    valve_damping : float > 0
        Damping ratio of a second-order valve or pilot [-].
    main_stage_hz : float >= 0
        Three stages: corner of the main stage's spool position loop [Hz].
    leakage_m3_per_s_Pa : float >= 0
        K = K_c + C_l [m^3/(s Pa)].
    supply_pressure_Pa : float >= 0
        p_s of the orifice flow law (0: linear flow) [Pa].
    coulomb_friction_N : float >= 0
        F_c [N].
    friction_velocity_m_s : float > 0
        v_s of the smoothed sign [m/s].
    io_delay_s : float >= 0
        tau_io [s].

    Raises
    ------
    ParameterError
        A value out of range (the message names it).
    """

    name: str
    piston_area_m2: float
    oil_bulk_modulus_Pa: float
    actuator_volume_m3: float
    valve_flow_gain_m3_per_s_V: float
    valve: str
    valve_hz: float
    valve_damping: float
    main_stage_hz: float
    leakage_m3_per_s_Pa: float
    supply_pressure_Pa: float
    coulomb_friction_N: float
    friction_velocity_m_s: float
    io_delay_s: float

    _POSITIVE = ('piston_area_m2', 'oil_bulk_modulus_Pa', 'actuator_volume_m3',
                 'valve_flow_gain_m3_per_s_V', 'valve_hz', 'valve_damping',
                 'friction_velocity_m_s')

    def __post_init__(self):
        if self.valve not in VALVES:
            raise ParameterError(f'actuator {self.name}: valve={self.valve!r}: expected one of '
                                 + ', '.join(VALVES))
        for f in fields(self):
            if f.name in ('name', 'valve'):
                continue
            v = getattr(self, f.name)
            positive = f.name in self._POSITIVE
            if not (math.isfinite(v) and (v > 0 if positive else v >= 0)):
                raise ParameterError(f'actuator {self.name}: {f.name}={v!r}: expected '
                                     + ('> 0' if positive else '>= 0'))
        if self.valve == 'three_stage' and not self.main_stage_hz > 0:
            raise ParameterError(f'actuator {self.name}: main_stage_hz: expected > 0 for a '
                                 'three-stage valve')

    @property
    def hydraulic_capacitance_m3_per_Pa(self) -> float:
        """``C_h = V_t/(4 beta)`` [m^3/Pa]."""
        return self.actuator_volume_m3 / (4.0 * self.oil_bulk_modulus_Pa)

    def valve_response(self, freqs_hz) -> np.ndarray:
        """The valve's spool per command ``x_v/u`` at `freqs_hz` [-], shape of the input."""
        s = 2j * np.pi * np.asarray(freqs_hz, dtype=float)
        w = 2.0 * np.pi * self.valve_hz
        if self.valve == 'first_order':
            return 1.0 / (s / w + 1.0)
        second = w * w / (s * s + 2.0 * self.valve_damping * w * s + w * w)
        if self.valve == 'second_order':
            return second
        return second / (s / (2.0 * np.pi * self.main_stage_hz) + 1.0)

    def valve_bandwidth_hz(self) -> float:
        """The valve's -3 dB frequency [Hz] (the first where ``|x_v/u|`` falls below
        ``1/sqrt(2)``)."""
        f = np.logspace(-1, 4, 20000)
        below = np.nonzero(np.abs(self.valve_response(f)) < 1.0 / math.sqrt(2.0))[0]
        return float(f[below[0]]) if below.size else math.inf

    def linear_plant(self, specimen: LinearSpecimen, dt: float) -> PlantModel:
        """The actuator and `specimen` linearized at rest, sampled at `dt`: the plant a perfect
        identification would find (the tests' independent reference).

        The orifice flow becomes ``k_q x_v`` (its slope at no load); the friction's smoothed
        sign its slope at rest, a viscous ``F_c / v_s`` (a small-motion model: it is not what
        the actuator does at test amplitudes).

        Returns
        -------
        PlantModel
            Continuous states ``[x, x', p_L, valve]`` sampled with the I/O delay
            (:func:`~seft_msgs_py.plant.sample_continuous`).
        """
        m, c, k = specimen.mass_kg, specimen.damping_N_s_per_m, specimen.stiffness_N_per_m
        area, kq = self.piston_area_m2, self.valve_flow_gain_m3_per_s_V
        inv_ch = 1.0 / self.hydraulic_capacitance_m3_per_Pa
        cf = self.coulomb_friction_N / self.friction_velocity_m_s
        w = 2.0 * math.pi * self.valve_hz
        nv = {'first_order': 1, 'second_order': 2, 'three_stage': 3}[self.valve]
        n = 3 + nv
        a = np.zeros((n, n))
        b = np.zeros((n, 1))
        a[0, 1] = 1.0
        a[1, :3] = [-k / m, -(c + cf) / m, area / m]
        xv = 5 if self.valve == 'three_stage' else 3     # the spool position's state
        a[2, :3] = [0.0, -area * inv_ch, -self.leakage_m3_per_s_Pa * inv_ch]
        a[2, xv] = kq * inv_ch
        if self.valve == 'first_order':
            a[3, 3], b[3, 0] = -w, w
        else:
            a[3, 4] = 1.0
            a[4, 3], a[4, 4], b[4, 0] = -w * w, -2.0 * self.valve_damping * w, w * w
            if self.valve == 'three_stage':
                wm = 2.0 * math.pi * self.main_stage_hz
                a[5, 3], a[5, 5] = wm, -wm
        force = np.zeros(n)
        force[1], force[2] = -cf, area
        accel = np.zeros(n)
        accel[:3] = a[1, :3]
        cc = np.vstack([force, np.eye(n)[0], np.eye(n)[1], accel])
        big, bb, cbig = sample_continuous(a, b, cc, dt, self.io_delay_s)
        return PlantModel(big, bb, cbig, dt, specimen=PlantSpecimen(m, c, k),
                          source=f'actuator {self.name} linearized at rest')

    def spread(self, fraction: float, rng: np.random.Generator) -> 'ActuatorSpec':
        """A Monte-Carlo draw: every nonzero physical parameter times ``U(1 - fraction,
        1 + fraction)``, independently (the valve model and the friction's smoothing kept).

        Parameters
        ----------
        fraction : float in [0, 0.9]
        rng : numpy.random.Generator

        Returns
        -------
        ActuatorSpec
        """
        if not 0 <= fraction <= 0.9:
            raise ParameterError(f'parameter actuator_spread={fraction!r}: expected 0 to 0.9')
        values = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ('name', 'valve', 'friction_velocity_m_s') or not v:
                continue
            values[f.name] = v * float(rng.uniform(1.0 - fraction, 1.0 + fraction))
        return replace(self, **values)


def _member(name: str, specimen: LinearSpecimen) -> ActuatorSpec:
    """The nominal member `name` of :data:`FAMILY` for `specimen`."""
    area, beta, volume = 2.0e-3, 1.0e9, 3.8e-3          # a 40 kN actuator with long hoses
    kq = 1.2e-4                                         # 0.6 m/s no-load at 10 V
    base = dict(name=name, piston_area_m2=area, oil_bulk_modulus_Pa=beta,
                actuator_volume_m3=volume, valve_flow_gain_m3_per_s_V=kq,
                valve='second_order', valve_hz=50.0, valve_damping=0.67, main_stage_hz=0.0,
                leakage_m3_per_s_Pa=2e-12, supply_pressure_Pa=0.0, coulomb_friction_N=0.0,
                friction_velocity_m_s=2e-3, io_delay_s=0.003)
    if name == 'valve_3_stage':
        base.update(valve='three_stage', valve_hz=160.0, valve_damping=0.7,
                    main_stage_hz=55.0, io_delay_s=0.0025)
    elif name == 'leaky':
        # worn seals: K = 1.35e-11, the real pole K k / (A^2 + C_h k) of the loaded actuator
        # at 0.5 Hz with a 1.19e6 N/m column (lower with a softer specimen)
        base.update(valve_hz=60.0, valve_damping=0.6, leakage_m3_per_s_Pa=1.35e-11)
    elif name == 'orifice_flow':
        base.update(valve_hz=55.0, valve_damping=0.7, supply_pressure_Pa=21e6)
    elif name == 'coulomb_friction':
        base.update(valve_hz=55.0, valve_damping=0.7, coulomb_friction_N=0.01 * area * 21e6)
    elif name == 'pure_delay':
        base.update(valve='first_order', valve_hz=80.0, io_delay_s=0.007)
    elif name != 'valve_2nd_order':
        raise ParameterError(f'parameter actuator_family={name!r}: expected one of '
                             + ', '.join(repr(n) for n in FAMILY))
    return ActuatorSpec(**base)


#: The members of the family (``actuator_family``), what each has that seft's rig has not.
FAMILY = {
    'valve_2nd_order': 'a second-order servo-valve (50 Hz, damping 0.67), 3 ms latency',
    'valve_3_stage': 'a three-stage valve: a 160 Hz pilot driving a 55 Hz main stage',
    'leaky': "worn seals: leakage 7 times the others', a real pole near 0.5 Hz with a stiff "
             'column',
    'orifice_flow': 'valve flow through an orifice, square root of the pressure drop '
                    '(21 MPa supply)',
    'coulomb_friction': 'Coulomb friction of the seals, 1 % of the stall force',
    'pure_delay': 'a fast first-order valve (80 Hz) behind a 7 ms pure delay',
}


def actuator_spec(params: Mapping) -> ActuatorSpec:
    """The actuator of ``actuator_family`` for the run's specimen, spread by
    ``actuator_spread`` with ``actuator_seed``.

    Raises
    ------
    ParameterError
        An unknown member or spread out of range.
    """
    spec = _member(params.get('actuator_family', 'valve_2nd_order'),
                   LinearSpecimen.from_parameters(params))
    spread = float(params.get('actuator_spread', 0.0) or 0.0)
    if spread:
        seed = int(params.get('actuator_seed', 1))
        spec = spec.spread(spread, np.random.default_rng([seed, 38]))
    return spec


class ActuatorRig:
    """An actuator of the family driving a linear specimen (Rig protocol, valve command).

    ``apply(u)`` holds ``u`` over ``[t_k, t_k+1)``; the valve sees it ``io_delay_s`` later.
    ``measure()`` reads the load cell ``A p_L - F_c tanh(x'/v_s)``, the displacement,
    velocity and acceleration at ``t_k``, through :class:`~seft_plant_sim.sensors.Sensors`.

    Parameters
    ----------
    spec : ActuatorSpec
    specimen : LinearSpecimen
    dt : float > 0
        Control period [s].
    sensors : Sensors, optional
        Default: noise-free, no accelerometer range.
    limits : SafetyLimits, optional
    rk4_substeps : int >= 1
        Runge-Kutta substeps per step (default 40: 50 us; the friction's smoothed sign and a
        160 Hz pilot need them).

    Raises
    ------
    ParameterError
        ``dt <= 0`` or ``rk4_substeps < 1``.
    """

    command_kind = COMMAND_VALVE

    def __init__(self, spec: ActuatorSpec, specimen: LinearSpecimen, dt: float,
                 sensors: Sensors | None = None, limits: SafetyLimits | None = None,
                 rk4_substeps: int = 40):
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise ParameterError(f'parameter dt={dt!r}: expected float > 0')
        if not (isinstance(rk4_substeps, int) and rk4_substeps >= 1):
            raise ParameterError(f'rk4_substeps={rk4_substeps!r}: expected int >= 1')
        self.spec = spec
        self.specimen = specimen
        self.dt = float(dt)
        self.sensors = sensors or Sensors()
        self.limits = limits or SafetyLimits()
        self.step = 0
        n, delta = split_delay(spec.io_delay_s, self.dt)
        self._history = deque([0.0] * (n + 1), maxlen=n + 1)      # u[k-n-1] .. u[k-1]
        self._late_from_history = n >= 1
        self._substeps = substeps(self.dt, delta, rk4_substeps)
        nv = {'first_order': 1, 'second_order': 2, 'three_stage': 3}[spec.valve]
        self._s = [0.0] * (3 + nv)                                  # x, v, p, valve
        self._rates = self._make_rates()

    @classmethod
    def from_parameters(cls, params: Mapping, *, rk4_substeps: int = 40) -> 'ActuatorRig':
        """Build from ``actuator_family``, ``actuator_spread``, ``actuator_seed``, the
        specimen (linear), ``dt``, the sensors' ``noise_*`` and range and the limits.

        Raises
        ------
        ParameterError
            A specimen that is not linear, or a value out of range.
        """
        if params.get('specimen_model', 'linear') != 'linear':
            raise ParameterError("rig_model 'actuator': expected specimen_model 'linear' (the "
                                 'family drives a linear specimen)')
        rng = float(params.get('accelerometer_range_m_s2', 0.0) or 0.0)
        return cls(actuator_spec(params), LinearSpecimen.from_parameters(params),
                   float(params['dt']), Sensors.from_parameters(params, rng if rng > 0 else None),
                   SafetyLimits.from_parameters(params), rk4_substeps=rk4_substeps)

    def _make_rates(self):
        sp, spec = self.specimen, self.spec
        inv_m, c, k = 1.0 / sp.mass_kg, sp.damping_N_s_per_m, sp.stiffness_N_per_m
        area = spec.piston_area_m2
        inv_ch = 1.0 / spec.hydraulic_capacitance_m3_per_Pa
        kq, leak = spec.valve_flow_gain_m3_per_s_V, spec.leakage_m3_per_s_Pa
        ps = spec.supply_pressure_Pa
        inv_ps = 1.0 / ps if ps > 0 else 0.0
        fc, inv_vs = spec.coulomb_friction_N, 1.0 / spec.friction_velocity_m_s
        w = 2.0 * math.pi * spec.valve_hz
        w2, zw2 = w * w, 2.0 * spec.valve_damping * w
        wm = 2.0 * math.pi * spec.main_stage_hz
        valve = spec.valve
        tanh, sqrt = math.tanh, math.sqrt

        def flow(xv, p):
            if not inv_ps:
                return kq * xv
            r = 1.0 - (p if xv >= 0.0 else -p) * inv_ps
            return kq * xv * sqrt(r) if r > 0.0 else 0.0

        # the derivatives as a tuple of six (a valve of fewer states pads with zeros, whose
        # rates stay zero), one function per valve (its kind read once, not at every call);
        # the same operations, in the same order, as the one function with a list of
        # before (bit for bit: tests/seft_plant_sim/test_actuator.py)
        if valve == 'first_order':
            def rates(x, v, p, xv, _4, _5, u):
                force = area * p - (fc * tanh(v * inv_vs) if fc else 0.0)
                acc = (force - c * v - k * x) * inv_m
                dp = (flow(xv, p) - area * v - leak * p) * inv_ch
                return v, acc, dp, (u - xv) * w, 0.0, 0.0
        elif valve == 'second_order':
            def rates(x, v, p, xv, dxv, _5, u):
                force = area * p - (fc * tanh(v * inv_vs) if fc else 0.0)
                acc = (force - c * v - k * x) * inv_m
                dp = (flow(xv, p) - area * v - leak * p) * inv_ch
                return v, acc, dp, dxv, w2 * (u - xv) - zw2 * dxv, 0.0
        else:
            def rates(x, v, p, y, dy, xv, u):
                force = area * p - (fc * tanh(v * inv_vs) if fc else 0.0)
                acc = (force - c * v - k * x) * inv_m
                dp = (flow(xv, p) - area * v - leak * p) * inv_ch
                return v, acc, dp, dy, w2 * (u - y) - zw2 * dy, wm * (y - xv)

        return rates

    def _rk4(self, s, u, h, n):
        """`n` classical Runge-Kutta steps of `h` [s] from the state list `s` under the held
        command `u` [V] (each state's stages ``s + h/2 k1``, ``s + h/2 k2``, ``s + h k3`` and
        ``s + h/6 (k1 + 2 (k2 + k3) + k4)``, unrolled over six scalars, the valve's unused
        ones zero: the family's rigs spent 2.9 of 8.6 s of a 1 kHz test in building and
        zipping lists)."""
        rates, size = self._rates, len(s)
        s0, s1, s2, s3, s4, s5 = list(s) + [0.0] * (6 - size)
        for _ in range(n):
            h2 = 0.5 * h
            a0, a1, a2, a3, a4, a5 = rates(s0, s1, s2, s3, s4, s5, u)
            b0, b1, b2, b3, b4, b5 = rates(s0 + h2 * a0, s1 + h2 * a1, s2 + h2 * a2,
                                           s3 + h2 * a3, s4 + h2 * a4, s5 + h2 * a5, u)
            c0, c1, c2, c3, c4, c5 = rates(s0 + h2 * b0, s1 + h2 * b1, s2 + h2 * b2,
                                           s3 + h2 * b3, s4 + h2 * b4, s5 + h2 * b5, u)
            d0, d1, d2, d3, d4, d5 = rates(s0 + h * c0, s1 + h * c1, s2 + h * c2,
                                           s3 + h * c3, s4 + h * c4, s5 + h * c5, u)
            h6 = h / 6.0
            s0 = s0 + h6 * (a0 + 2.0 * (b0 + c0) + d0)
            s1 = s1 + h6 * (a1 + 2.0 * (b1 + c1) + d1)
            s2 = s2 + h6 * (a2 + 2.0 * (b2 + c2) + d2)
            s3 = s3 + h6 * (a3 + 2.0 * (b3 + c3) + d3)
            s4 = s4 + h6 * (a4 + 2.0 * (b4 + c4) + d4)
            s5 = s5 + h6 * (a5 + 2.0 * (b5 + c5) + d5)
        return [s0, s1, s2, s3, s4, s5][:size]

    @property
    def time_s(self) -> float:
        """Time of the current sample [s]."""
        return self.step * self.dt

    @property
    def state(self) -> np.ndarray:
        """Copy of the state ``[x, x', p_L, valve states]`` at t_k."""
        return np.array(self._s)

    def _outputs(self):
        s = self._s
        x, v, p = s[0], s[1], s[2]
        spec, sp = self.spec, self.specimen
        force = spec.piston_area_m2 * p - (spec.coulomb_friction_N
                                           * math.tanh(v / spec.friction_velocity_m_s)
                                           if spec.coulomb_friction_N else 0.0)
        acc = (force - sp.damping_N_s_per_m * v - sp.stiffness_N_per_m * x) / sp.mass_kg
        return x, v, acc, force

    def true_force(self) -> float:
        """The load cell's true force at the current sample [N]."""
        return self._outputs()[3]

    def measure(self) -> Measurement:
        """Sensor readings at the current sample."""
        x, v, a, f = self._outputs()
        return self.sensors.read(self.step, self.step * self.dt, x, v, a, f)

    def apply(self, command: float) -> None:
        """Hold the valve command `command` [V] over the current step and advance."""
        u = float(command)
        hist = self._history
        u_early = hist[0]
        u_late = hist[1] if self._late_from_history else u
        n_early, h_early, n_late, h_late = self._substeps
        s = self._rk4(self._s, u_early, h_early, n_early)
        self._s = self._rk4(s, u_late, h_late, n_late)
        hist.append(u)
        self.step += 1

    def limit_violation(self) -> str | None:
        """Stroke/force limit check on the true state at the current sample."""
        x, _, _, f = self._outputs()
        return self.limits.violation(self.step * self.dt, x, f)
