"""The force servo controller: the reference study's loop-shaping controller, discretized."""

from dataclasses import dataclass
import math

import numpy as np
from scipy import signal

from seft_msgs_py.calibration import CALIBRATIONS, DEFAULT_CALIBRATION, controller_gain_V_per_N
from seft_msgs_py.errors import ParameterError
from seft_msgs_py.prediction import (
    PREDICTION_ORDER,
    PREDICTION_RIDGE,
    PREDICTION_WINDOW_S,
    SampleHistory,
    window_steps,
)

__all__ = ['DiscreteFilter', 'ForceServoController', 'SaturationInterlock', 'LOOP_SHAPING_NUM',
           'ControllerTF',
           'LOOP_SHAPING_DEN', 'FORCE_CONTROLLERS', 'TangentLoopShaping', 'ReferencePlayout',
           'REFERENCE_EXTRAPOLATIONS', 'PREDICTION_ORDER', 'PREDICTION_WINDOW_S',
           'PREDICTION_RIDGE', 'prediction_window_steps', 'specimen_denominator']

#: Numerator of C_f(s) = 37 / (s^2 + 17.14 s + 4002) [V/N] (paper Eq. 3.1) in the default
#: reading, V/lbf: 37/4.448 = 8.318 V/N (:mod:`seft_msgs_py.calibration`; 'si': 37 V/N).
LOOP_SHAPING_NUM = (CALIBRATIONS[DEFAULT_CALIBRATION].controller_gain_V_per_N,)
#: Denominator of C_f(s) (paper Eq. 3.1).
LOOP_SHAPING_DEN = (1.0, 17.14, 4002.0)

#: The force controller designs (parameter ``force_controller``), :class:`ForceServoController`.
FORCE_CONTROLLERS = ('loop_shaping', 'integral', 'velocity_feedback', 'tangent_loop_shaping',
                     'specimen_loop_shaping', 'transfer_function')


def specimen_denominator(params) -> tuple[float, float, float]:
    """The denominator of C_f(s) that cancels the rig's own specimen, ``(1, c/m, k/m)``.

    Paper Eq. 3.1's ``s^2 + 17.14 s + 4002`` is the study's specimen's
    ``(m s^2 + c s + k)/m``; ``specimen_loop_shaping`` and ``tangent_loop_shaping`` (whose
    elastic design it is) take it from the rig's ``mass_kg``, ``damping_N_s_per_m`` and
    ``stiffness_N_per_m`` (the study's rig: ``(1, 17.14, 4003.8)``).

    Parameters
    ----------
    params : mapping
        The rig's parameters (absent keys: the schema's defaults).

    Returns
    -------
    tuple of float
        ``(1, c/m [1/s], k/m [1/s^2])``.

    Raises
    ------
    ParameterError
        If ``mass_kg`` is not > 0 or ``stiffness_N_per_m`` is not > 0.
    """
    from seft_msgs_py.parameters import spec

    def get(name):
        return float(params[name] if name in params else spec(name).default)

    m, c, k = get('mass_kg'), get('damping_N_s_per_m'), get('stiffness_N_per_m')
    for name, value in (('mass_kg', m), ('stiffness_N_per_m', k)):
        if not (math.isfinite(value) and value > 0):
            raise ParameterError(f'parameter {name}={value!r}: expected float > 0 (the '
                                 "specimen the force controller's C_f cancels)")
    return (1.0, c / m, k / m)


class DiscreteFilter:
    """A causal discrete transfer function ``b(z)/a(z)`` stepped one sample at a time.

    Direct form II transposed with plain Python floats (the same recursion as
    ``scipy.signal.lfilter``, which only filters whole arrays), written out for a second-order
    section (the force controller and the instability monitor's filters): one step costs a
    few hundred nanoseconds, which matters at 500 Hz in a Python node and in ``seft
    simulate``.

    Parameters
    ----------
    b, a : sequence of float
        Numerator and denominator coefficients in descending powers of z; ``a[0] != 0``.

    Raises
    ------
    ParameterError
        If ``a[0] == 0`` or a coefficient is not finite.
    """

    def __init__(self, b, a):
        b = np.atleast_1d(np.asarray(b, dtype=float))
        a = np.atleast_1d(np.asarray(a, dtype=float))
        if a[0] == 0 or not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            raise ParameterError('filter coefficients: expected finite values with a[0] != 0')
        n = max(len(a), len(b))
        b = np.concatenate([b, np.zeros(n - len(b))]) / a[0]
        a = np.concatenate([a, np.zeros(n - len(a))]) / a[0]
        self.b = tuple(float(v) for v in b)
        self.a = tuple(float(v) for v in a)
        self._z = [0.0] * (n - 1)
        # second order (the controller, the monitor's Butterworth pair): written out
        self._biquad = (self.b + self.a[1:]) if n == 3 else None

    def reset(self) -> None:
        """Zero the filter state."""
        self._z = [0.0] * len(self._z)

    def step(self, x: float) -> float:
        """Filter one input sample and return the output sample."""
        z = self._z
        if self._biquad is not None:
            b0, b1, b2, a1, a2 = self._biquad
            y = b0 * x + z[0]
            z[0] = b1 * x - a1 * y + z[1]
            z[1] = b2 * x - a2 * y
            return y
        b, a = self.b, self.a
        y = b[0] * x + (z[0] if z else 0.0)
        n = len(z)
        for i in range(n):
            nxt = z[i + 1] if i + 1 < n else 0.0
            z[i] = b[i + 1] * x - a[i + 1] * y + nxt
        return y


@dataclass(frozen=True)
class ControllerDesign:
    """Continuous controller ``num(s)/den(s)`` [V/N] and its discretization."""

    num: tuple
    den: tuple
    dt: float
    method: str


def _discrete_coefficients(num, den):
    """``(bz, az)`` in powers of ``z^-1`` of ``num(z)/den(z)`` given in descending powers of
    z (``scipy.signal.dlti``'s convention): the numerator padded at the front to the
    denominator's length."""
    num = np.trim_zeros(np.asarray(num, dtype=float), 'f')
    den = np.trim_zeros(np.asarray(den, dtype=float), 'f')
    if num.size == 0:
        num = np.zeros(1)
    if den.size == 0 or num.size > den.size:
        raise ParameterError('force_controller_tf: expected a proper transfer function in z '
                             '(the numerator of at most the degree of the denominator)')
    bz = np.concatenate([np.zeros(den.size - num.size), num]) / den[0]
    return bz, den / den[0]


@dataclass(frozen=True)
class ControllerTF:
    """A lab's force controller as a transfer function (``force_controller_tf``).

    Attributes
    ----------
    num, den : tuple of float
        Force error [N] to valve command [V]: polynomials in s (continuous) or in z
        (discrete), descending powers.
    discrete : bool
        Given in z at the run's period.
    prewarp_hz : float
        Continuous: the frequency at which Tustin's discretization is exact [Hz] (0: none).
    method : str
        How it was made (a design's name and source), for the reports.
    """

    num: tuple
    den: tuple
    discrete: bool = False
    prewarp_hz: float = 0.0
    method: str = ''

    def to_mapping(self, dt: float | None = None) -> dict:
        """``{num, den, dt (the period if discrete, else 0), prewarp_hz, method}``."""
        doc = {'num': [float(v) for v in self.num], 'den': [float(v) for v in self.den],
               'dt': float(dt) if self.discrete and dt else 0.0}
        if self.prewarp_hz:
            doc['prewarp_hz'] = float(self.prewarp_hz)
        if self.method:
            doc['method'] = self.method
        return doc

    @classmethod
    def from_parameter(cls, value, *, dt: float,
                       where: str = 'parameter force_controller_tf') -> 'ControllerTF':
        """From the parameter's mapping (or its JSON).

        Raises
        ------
        ParameterError
            'none', not a mapping, coefficients that are not finite numbers, an improper
            transfer function, or a discrete one of another period than `dt` (the message
            names the field).
        """
        if value in (None, '', 'none'):
            raise ParameterError(f"{where}: force_controller 'transfer_function' needs the "
                                 'controller: {num: [...], den: [...], dt: 0 (continuous, s) or '
                                 "the run's period (discrete, z)}")
        from seft_msgs_py.parameters import mapping_value
        doc = mapping_value(value, where=where, expected='a transfer function {num, den, dt}')
        unknown = sorted(set(doc) - {'num', 'den', 'dt', 'prewarp_hz', 'method'})
        if unknown:
            raise ParameterError(f'{where}: unknown field(s) {", ".join(unknown)}; expected num, '
                                 'den, dt, prewarp_hz, method')
        coeffs = {}
        for key in ('num', 'den'):
            v = doc.get(key)
            if not (isinstance(v, (list, tuple)) and v and all(
                    isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                    for x in v)):
                raise ParameterError(f'{where}.{key}={v!r}: expected a non-empty list of finite '
                                     'numbers (descending powers of s or z)')
            coeffs[key] = tuple(float(x) for x in v)
        if not any(coeffs['den']):
            raise ParameterError(f'{where}.den: expected a non-zero denominator')
        period = doc.get('dt', 0.0) or 0.0
        if isinstance(period, bool) or not isinstance(period, (int, float)) or period < 0:
            raise ParameterError(f'{where}.dt={period!r}: expected 0 (continuous) or the period '
                                 '[s]')
        discrete = period > 0
        if discrete and abs(period - dt) > 1e-9 * dt:
            raise ParameterError(f"{where}.dt={period:g}: a discrete controller must have the "
                                 f"run's period dt={dt:g} s")
        num = np.trim_zeros(np.array(coeffs['num']), 'f')
        den = np.trim_zeros(np.array(coeffs['den']), 'f')
        if num.size > den.size:
            raise ParameterError(f'{where}: expected a proper transfer function (num of degree '
                                 f'{num.size - 1} over den of degree {den.size - 1})')
        prewarp = doc.get('prewarp_hz', 0.0) or 0.0
        if isinstance(prewarp, bool) or not isinstance(prewarp, (int, float)) or prewarp < 0 \
                or (prewarp and prewarp >= 0.5 / dt):
            raise ParameterError(f'{where}.prewarp_hz={prewarp!r}: expected 0 or a frequency '
                                 'below the Nyquist frequency [Hz]')
        return cls(coeffs['num'], coeffs['den'], discrete, float(prewarp),
                   str(doc.get('method', '')))


class ForceServoController:
    """Force controller of the servo valve, one of :data:`FORCE_CONTROLLERS`, at period ``dt``.

    The valve command is ``u[k] = sat(C_e(z) e[k] + g_v (v[k] + T_v a[k]))`` with the force
    error ``e[k] = f_r[k] - f_m[k]`` [N], the measured velocity ``v`` [m/s] and acceleration
    ``a`` [m/s^2] of the specimen, and the saturation ``|u| <= valve_limit_V`` [V]. The
    error path ``C_e`` and the velocity gain ``g_v`` [V s/m] and lead ``T_v`` [s] are set by
    the design (parameter ``force_controller``, :meth:`from_parameters`):

    ``loop_shaping`` (default; the reference study)
        ``C_e(s) = C_f(s) = 37/(s^2 + 17.14 s + 4002)``, ``g_v = 0``. The gain 37 is in volts
        per unit of force of the rig calibration (``rig_calibration``,
        :mod:`seft_msgs_py.calibration`): V/lbf by default, 37/4.448 V/N.
    ``specimen_loop_shaping``
        The study's loop-shaping rule for this rig's own specimen (``mass_kg``,
        ``damping_N_s_per_m``, ``stiffness_N_per_m``): ``C_e(s) = g/(s^2 + (c/m) s + k/m)``,
        whose poles cancel the control-structure-interaction zero of the valve-to-force plant
        ``(k_q/A)(m s^2 + c s + k)/s`` at the specimen's natural frequency, with the gain
        ``g`` of Eq. 3.1: the loop ``g k_q m/(A s)`` and its crossover are those of the study
        whatever the stiffness. For the study's specimen it is Eq. 3.1 but for the rounding
        of 4002 (k/m = 4003.8 s^-2); a rig of another stiffness (a second pier) needs it:
        with Eq. 3.1 a 1.6 k specimen loses force control (the valve saturates).
    ``integral``
        ``C_e(s) = C_f(s) (1 + w_i/s)``, ``w_i = 2 pi force_integral_hz``: integral action
        below w_i on top of the loop-shaping controller (a type-2 force loop).
    ``velocity_feedback``
        Velocity feedback compensation of the control-structure interaction (Dimig et al.
        1999; Zhao et al. 2003, 2005): ``g_v = A/k_q`` so that the valve supplies the flow the
        moving specimen takes, ``k_q g_v v = A v``, and the oil column sees only the force
        error: ``f/e = A k_q C_e(s)/(C_h s + K)`` whatever the specimen's (tangent)
        stiffness, with ``C_h = V_t/(4 beta)`` and ``K = K_c + C_l``. ``C_e(s) = K_p (1 +
        w_h/s)`` with ``w_h = K/C_h`` cancels the leakage pole (19 Hz on the default rig, so
        that a proportional controller alone would leave a static loop gain of 0.6) and
        ``K_p = 2 pi f_c C_h/(A k_q)`` puts the crossover of the resulting integrator
        ``2 pi f_c/s`` at ``force_crossover_hz``. The fed-back velocity is low-passed (2nd-
        order Butterworth at ``velocity_filter_hz``) and may be advanced by ``T_v =
        velocity_lead_s`` with the measured acceleration. Measured limitation on the
        simulated rig: the velocity reaches the valve 5.5 ms (latency and spool) plus the
        filter's delay late; the flow mismatch ``A tau a`` acts through the stiff oil column
        as a large added mass, and the loop has an unstable 2-5 Hz mode (spectral radius
        1.010-1.018 for f_c = 6-20 Hz), so this design is provided for rigs with a fast
        valve and is not recommended here (docs: design, "Force control").

    Discretization (``scipy.signal.cont2discrete``): the loop-shaping ``C_f`` by Tustin
    (bilinear) with frequency prewarping at its resonance ``w0 = sqrt(den[2])`` (sqrt(4002)
    rad/s = 10.07 Hz), at the prewarped period ``2*tan(w0*dt/2)/w0``. Why: the controller's
    lightly damped poles are there to cancel the control-structure-interaction zero at the
    specimen's natural frequency, so they must land exactly there (prewarping makes the
    discrete response exact at w0); Tustin maps the stable poles to stable discrete poles and
    adds no phase lag (measured: within 1.7 % in magnitude and 0.1 deg in phase of the
    continuous controller up to 25 Hz at dt = 2 ms), whereas a zero-order-hold or Euler
    emulation adds about half a sample of lag, which the 12 Hz crossover cannot spare. The
    integrator ``w_i/s`` is discretized by Tustin at the same period and acts on the output
    of the proportional or loop-shaping part; it is frozen while the valve command saturates
    (conditional integration, no wind-up). The velocity path is static.

    Parameters
    ----------
    dt : float > 0
        Control period [s].
    valve_limit_V : float > 0
        Valve command saturation [V] (reference rig: 10 V).
    num, den : sequence of float
        Continuous error path without the integral action [V/N] (default: paper Eq. 3.1 in
        V/lbf); a second-order ``den`` is prewarped at its resonance.
    integral_hz : float >= 0
        Corner ``w_i/(2 pi)`` of the integral action [Hz] (0: none).
    velocity_gain_V_s_per_m : float >= 0
        ``g_v`` [V/(m/s)] (0: no velocity path).
    velocity_lead_s : float >= 0
        ``T_v`` [s].
    kind : str
        Name of the design, for messages.
    prewarp_rad_s : float, optional
        Prewarping frequency of a second-order ``den`` [rad/s] (default: its resonance).

    Attributes
    ----------
    bz, az : ndarray
        Discrete error path ``C_e(z)`` including the integral action, descending powers of z.
    velocity_gain_V_s_per_m, velocity_lead_s : float

    Raises
    ------
    ParameterError
        If ``dt <= 0``, ``valve_limit_V <= 0`` or a gain, corner or lead is negative or not
        finite.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eq. 3.1, Figs. 3-4;
    N. Nakata (2012), Effective force testing using a robust loop shaping controller,
    Earthquake Eng. Struct. Dyn. 42(2).
    J. P. Dimig, C. K. Shield, C. W. French, F. Bailey and A. Clark, Effective force testing:
    a method of seismic simulation for structural testing, J. Struct. Eng. 125(9), 1999,
    1028-1037 (velocity feedback added because force control alone failed at the structure's
    natural frequency).
    J. Zhao, C. French, C. Shield and T. Posbergh, Considerations for the development of
    real-time dynamic testing using servo-hydraulic actuation, Earthquake Eng. Struct. Dyn.
    32(11), 2003, 1773-1794, and Comparison of tests of a nonlinear structure using a shake
    table and the EFT method, J. Struct. Eng. 131(11), 2005, 1755-1763 (velocity
    compensation ``A/k_q`` of the natural velocity feedback).
    """

    def __init__(self, dt: float, valve_limit_V: float = 10.0,
                 num=LOOP_SHAPING_NUM, den=LOOP_SHAPING_DEN, *, integral_hz: float = 0.0,
                 velocity_gain_V_s_per_m: float = 0.0, velocity_lead_s: float = 0.0,
                 velocity_filter_hz: float = 0.0, kind: str = 'loop_shaping',
                 prewarp_rad_s: float | None = None, discrete: bool = False):
        if not dt > 0:
            raise ParameterError(f'parameter dt={dt!r}: expected float > 0')
        if not valve_limit_V > 0:
            raise ParameterError(f'parameter valve_limit_V={valve_limit_V!r}: expected float > 0')
        for name, value in (('force_integral_hz', integral_hz),
                            ('velocity_feedback_gain', velocity_gain_V_s_per_m),
                            ('velocity_lead_s', velocity_lead_s),
                            ('velocity_filter_hz', velocity_filter_hz)):
            if not (math.isfinite(value) and value >= 0):
                raise ParameterError(f'parameter {name}={value!r}: expected float >= 0')
        self.dt = float(dt)
        self.valve_limit_V = float(valve_limit_V)
        self.kind = str(kind)
        den = tuple(float(v) for v in den)
        num = tuple(float(v) for v in num)
        if discrete:                           # given in z: as it is
            bz, az = _discrete_coefficients(num, den)
            period, method = self.dt, 'given in z'
        elif prewarp_rad_s is not None and len(den) != 3:    # prewarped at a given frequency
            w0 = float(prewarp_rad_s)
            period = 2.0 * np.tan(w0 * self.dt / 2.0) / w0
            method = f'bilinear, prewarped at {w0:.4g} rad/s'
        elif len(den) == 3:                    # resonant loop shaping: prewarp at w0
            w0 = (float(np.sqrt(den[-1] / den[0])) if prewarp_rad_s is None
                  else float(prewarp_rad_s))
            period = 2.0 * np.tan(w0 * self.dt / 2.0) / w0
            method = f'bilinear, prewarped at {w0:.4g} rad/s'
        else:
            period, method = self.dt, 'bilinear'
        if discrete:
            pass
        elif len(den) == 1 and len(num) == 1:    # static gain (cont2discrete adds a z=1 pair)
            bz, az = np.array([num[0] / den[0]]), np.array([1.0])
        else:
            bz, az, _ = signal.cont2discrete((num, den), period, method='bilinear')
            bz, az = np.ravel(bz), np.ravel(az)
        self._filter = DiscreteFilter(bz, az)
        self.integral_hz = float(integral_hz)
        # Tustin integrator y[k] = y[k-1] + ki (x[k] + x[k-1])
        self._ki = 0.0
        if self.integral_hz > 0:
            wi = 2.0 * math.pi * self.integral_hz
            bi, ai, _ = signal.cont2discrete(((wi,), (1.0, 0.0)), period, method='bilinear')
            bi, ai = np.ravel(bi) / ai.ravel()[0], np.ravel(ai) / ai.ravel()[0]
            self._ki = float(bi[0])
            # C_e = C (1 + I) = b (a_i + b_i) / (a a_i)
            bz = np.polymul(bz, np.polyadd(ai, bi))
            az = np.polymul(az, ai)
            method += f'; integral action below {self.integral_hz:g} Hz (bilinear)'
        self.design = ControllerDesign(num, den, self.dt, method)
        self.bz = bz
        self.az = az
        self.velocity_gain_V_s_per_m = float(velocity_gain_V_s_per_m)
        self.velocity_lead_s = float(velocity_lead_s)
        self._gv = self.velocity_gain_V_s_per_m
        self._gva = self._gv * self.velocity_lead_s
        self.velocity_filter_hz = float(velocity_filter_hz)
        self._vfilter = None
        if self._gv and self.velocity_filter_hz > 0:
            if not self.velocity_filter_hz < 0.5 / self.dt:
                raise ParameterError(f'parameter velocity_filter_hz={velocity_filter_hz!r}: '
                                     'expected below the Nyquist frequency')
            bv, av = signal.butter(2, self.velocity_filter_hz, fs=1.0 / self.dt)
            self._vfilter = DiscreteFilter(bv, av)
        self._plain = self._ki == 0.0 and self._gv == 0.0
        self._i = 0.0                           # integrator output
        self._x_prev = 0.0                      # its previous input
        self.saturated = False

    @classmethod
    def from_parameters(cls, params) -> 'ForceServoController':
        """Build from the parameter schema.

        Reads ``dt``, ``valve_limit_V``, ``rig_calibration``, ``force_controller``,
        ``force_integral_hz``, ``force_crossover_hz``, ``velocity_lead_s``,
        ``velocity_filter_hz`` and, for the
        velocity designs, the nominal hydraulics ``piston_area_m2``, ``oil_bulk_modulus_Pa``,
        ``actuator_volume_m3`` and ``valve_flow_gain_m3_per_s_V`` (absent keys: the schema's
        defaults).

        Raises
        ------
        ParameterError
            Unknown ``force_controller`` or a value out of range.
        """
        from seft_msgs_py.calibration import valve_flow_gain_m3_per_s_V
        from seft_msgs_py.parameters import spec

        def get(name):
            return params[name] if name in params else spec(name).default

        kind = get('force_controller')
        if kind not in FORCE_CONTROLLERS:
            raise ParameterError(f'parameter force_controller={kind!r}: expected one of '
                                 + ', '.join(repr(c) for c in FORCE_CONTROLLERS))
        if kind == 'tangent_loop_shaping':
            return TangentLoopShaping.from_parameters(params)
        dt, limit = float(params['dt']), float(params['valve_limit_V'])
        if kind == 'transfer_function':
            tf = ControllerTF.from_parameter(params.get('force_controller_tf', 'none'), dt=dt)
            return cls(dt, limit, num=tf.num, den=tf.den, discrete=tf.discrete,
                       prewarp_rad_s=(2.0 * math.pi * tf.prewarp_hz if tf.prewarp_hz else None),
                       kind=kind)
        fi = float(get('force_integral_hz'))
        if kind in ('loop_shaping', 'integral'):
            return cls(dt, limit, num=(controller_gain_V_per_N(params),),
                       integral_hz=fi if kind == 'integral' else 0.0, kind=kind)
        if kind == 'specimen_loop_shaping':
            return cls(dt, limit, num=(controller_gain_V_per_N(params),),
                       den=specimen_denominator(params), kind=kind)
        area = float(get('piston_area_m2'))
        c_h = float(get('actuator_volume_m3')) / (4.0 * float(get('oil_bulk_modulus_Pa')))
        k_q = float(valve_flow_gain_m3_per_s_V(params))
        fc = float(get('force_crossover_hz'))
        if not (area > 0 and c_h > 0 and k_q > 0 and fc > 0):
            raise ParameterError(f'parameter force_crossover_hz={fc!r}: expected float > 0 '
                                 '(and positive piston area, volume, bulk modulus, flow gain)')
        kp = 2.0 * math.pi * fc * c_h / (area * k_q)
        leak = (float(get('valve_pressure_coefficient_m3_per_s_Pa'))
                + float(get('leakage_coefficient_m3_per_s_Pa')))
        return cls(dt, limit, num=(kp,), den=(1.0,),
                   integral_hz=leak / c_h / (2.0 * math.pi),
                   velocity_gain_V_s_per_m=area / k_q,
                   velocity_filter_hz=float(get('velocity_filter_hz')),
                   velocity_lead_s=float(get('velocity_lead_s')), kind=kind)

    @property
    def uses_motion(self) -> bool:
        """True when the command uses the measured velocity (and acceleration)."""
        return self._gv != 0.0

    def continuous(self) -> signal.TransferFunction:
        """The continuous error path without integral action [V/N]."""
        return signal.TransferFunction(self.design.num, self.design.den)

    def discrete(self) -> signal.TransferFunction:
        """The discretized error path ``C_e(z)`` [V/N] with ``dt`` (integral action included)."""
        return signal.TransferFunction(self.bz, self.az, dt=self.dt)

    def state_space(self):
        """The linear controller (no saturation) as a discrete state space.

        Returns
        -------
        a, b, c, d : ndarray
            ``x[k+1] = a x[k] + b w[k]``, ``u[k] = c x[k] + d w[k]`` with the inputs
            ``w = (e, v, a)`` [N, m/s, m/s^2]; shapes (n, n), (n, 3), (1, n), (1, 3).
        """
        nb = max(len(self.az), len(self.bz))
        bz = np.concatenate([np.zeros(nb - len(self.bz)), self.bz])
        az = np.concatenate([self.az, np.zeros(nb - len(self.az))])
        a, b, c, d = signal.tf2ss(bz, az)
        n = a.shape[0]
        b3 = np.zeros((n, 3))
        b3[:, 0] = b[:, 0]
        d3 = np.array([[d[0, 0], self._gv, self._gva]])
        c = c.reshape(1, n)
        if self._vfilter is None:
            return a, b3, c, d3
        # velocity path g_v H(z) (v + T_v a), H the Butterworth low-pass, in series
        av_, bv_, cv_, dv_ = signal.tf2ss(self._vfilter.b, self._vfilter.a)
        nv = av_.shape[0]
        a2 = np.zeros((n + nv, n + nv))
        a2[:n, :n], a2[n:, n:] = a, av_
        b2 = np.zeros((n + nv, 3))
        b2[:n] = b3
        b2[n:, 1] = bv_[:, 0]
        b2[n:, 2] = bv_[:, 0] * self.velocity_lead_s
        c2 = np.hstack([c, self._gv * cv_.reshape(1, nv)])
        d3 = np.array([[d[0, 0], self._gv * dv_[0, 0], self._gva * dv_[0, 0]]])
        return a2, b2, c2, d3

    def reset(self) -> None:
        """Zero the controller state."""
        self._filter.reset()
        if self._vfilter is not None:
            self._vfilter.reset()
        self._i = 0.0
        self._x_prev = 0.0
        self.saturated = False

    def step(self, reference_force_N: float, measured_force_N: float,
             velocity_m_s: float = 0.0, acceleration_m_s2: float = 0.0,
             displacement_m: float = 0.0) -> float:
        """Return the valve command [V] for one sample.

        Parameters
        ----------
        reference_force_N, measured_force_N : float
            f_r[k], f_m[k] [N].
        velocity_m_s, acceleration_m_s2 : float
            Measured velocity [m/s] and acceleration [m/s^2] of the specimen at step k; used
            only by the velocity designs (default 0: the loop-shaping call ``step(f_r, f_m)``).
        displacement_m : float
            Measured displacement [m] at step k; used only by ``tangent_loop_shaping``.
        """
        e = reference_force_N - measured_force_N
        f = self._filter
        if f._biquad is None:
            u = f.step(e)
        else:                                    # f.step(e), written out (the hot path)
            z = f._z
            b0, b1, b2, a1, a2 = f._biquad
            u = b0 * e + z[0]
            z[0] = b1 * e - a1 * u + z[1]
            z[1] = b2 * e - a2 * u
        lim = self.valve_limit_V             # saturate: min(max(u, -lim), lim); NaN passes
        if self._plain:
            if u > lim:
                self.saturated = True
                return lim
            if u < -lim:
                self.saturated = True
                return -lim
            self.saturated = False
            return u
        ki = self._ki
        if ki:
            i_new = self._i + ki * (u + self._x_prev)
            self._x_prev = u
            u = u + i_new
        if self._vfilter is None:
            u += self._gv * velocity_m_s + self._gva * acceleration_m_s2
        else:
            u += self._gv * self._vfilter.step(velocity_m_s
                                               + self.velocity_lead_s * acceleration_m_s2)
        if u > lim or u < -lim:
            self.saturated = True               # conditional integration: i held
            return lim if u > 0 else -lim
        if ki:
            self._i = i_new
        self.saturated = False
        return u


class TangentLoopShaping(ForceServoController):
    """The study's loop shaping with its control-structure-interaction cancellation scheduled
    on the member's tangent stiffness (``force_controller: tangent_loop_shaping``).

    Why: the valve drives a flow, so below the oil column the valve-to-force plant is the
    specimen's dynamic stiffness times an integrator, ``P(s) ~ (k_q/A)(m s^2 + c s + k_t)/s``
    (control-structure interaction, Dyke et al. 1995; :mod:`seft_plant_sim.servohydraulic`),
    and ``C_f(s) = g/(s^2 + (c/m) s + k/m)``, whose poles are the specimen's
    ``(m s^2 + c s + k)/m`` (paper Eq. 3.1, ``s^2 + 17.14 s + 4002`` for the study's
    specimen; here the rig's own ``mass_kg``, ``damping_N_s_per_m`` and
    ``stiffness_N_per_m``, :func:`specimen_denominator`), cancels that zero: the loop is
    ``g m k_q/(A s)``, an integrator. When the member yields its tangent stiffness k_t falls
    (to a tenth for the default Bouc-Wen member), the zero moves down and the loop gain below
    it falls with k_t (at 1 Hz from 13.3 to 1.31): the force lags and undershoots. Here the
    cancellation follows the member::

        C(s; rho) = g / (s^2 + (c/m) s + (k/m) rho),   rho = k_t(t + h) / k

    so that the loop stays ``g m k_q/(A s)`` whatever k_t (gain scheduling on the measured
    operating point, Rugh and Shamma 2000), with ``k`` the member's elastic stiffness as
    identified (so that an elastic member is ``rho = 1``, ``specimen_loop_shaping``, however
    well its stiffness is known). ``k_t(t + h)`` is the tangent stiffness predicted
    ``h = force_tangent_horizon_s`` after the sample, when the command acts on the flow
    (I/O latency and valve lag), by
    :meth:`~seft_ros.core.hysteresis.HystereticMember.tangent_ahead`: a Bouc-Wen model
    anchored on the measured restoring force and identified online
    (:mod:`seft_ros.core.hysteresis`). Measured on the default Bouc-Wen member, embedded
    record at 1000 N, alpha = 0: the displacement NRMS falls from 43.5 % (``loop_shaping``)
    to about 2 % (docs: design, "Force control"); with the tangent of the present sample instead of
    the predicted one, 19 %.

    Discretization: the state ``(u, u')`` of ``u'' + (c/m) u' + (k/m) rho u = g e`` by the
    trapezoidal rule (Tustin) at the period prewarped at the elastic resonance (as
    :class:`ForceServoController`), with ``rho`` of the current sample: at ``rho = 1`` the
    output is that of ``specimen_loop_shaping`` to rounding, and a change of ``rho`` changes the
    command's curvature, not the command (no jump). ``bz``, ``az`` and
    :meth:`~ForceServoController.state_space` are those of the elastic member (``rho = 1``):
    the stability map,
    the guard and the ``model`` compensator's force-loop inverse use them.

    Parameters
    ----------
    dt, valve_limit_V, num, den
        As :class:`ForceServoController` (``den`` second order: ``(1, 2 zeta w, w^2)``;
        :meth:`from_parameters`: the rig's own ``(1, c/m, k/m)``).
    member : HystereticMember
        The member's model.
    horizon_s : float >= 0
        h [s].

    Raises
    ------
    ParameterError
        As :class:`ForceServoController`; ``den`` not second order or `horizon_s` < 0.

    References
    ----------
    N. Nakata and S. Combs, Eq. 3.1; S. J. Dyke et al. (1995), J. Eng. Mech. 121(2);
    W. J. Rugh and J. S. Shamma, Research on gain scheduling, Automatica 36(10), 2000,
    1401-1425; :mod:`seft_ros.core.hysteresis`.
    """

    #: The range of rho: a stiffness below 1 % or above twice the configured one is taken
    #: as that bound (the filter stays well damped).
    RHO_RANGE = (0.01, 2.0)

    def __init__(self, dt: float, valve_limit_V: float = 10.0, num=LOOP_SHAPING_NUM,
                 den=LOOP_SHAPING_DEN, *, member, horizon_s: float):
        super().__init__(dt, valve_limit_V, num, den, kind='tangent_loop_shaping')
        if len(self.design.den) != 3 or len(self.design.num) != 1:
            raise ParameterError('tangent_loop_shaping: expected C_f = g/(s^2 + b s + c)')
        if not (math.isfinite(horizon_s) and horizon_s >= 0):
            raise ParameterError(f'parameter force_tangent_horizon_s={horizon_s!r}: expected '
                                 'float >= 0')
        d0, d1, d2 = self.design.den
        self._g = self.design.num[0] / d0
        self._c1, self._w2 = d1 / d0, d2 / d0
        w0 = math.sqrt(self._w2)
        self._h = math.tan(w0 * self.dt / 2.0) / w0          # half the prewarped period
        self.member = member
        self.horizon_s = float(horizon_s)
        self.rho = 1.0
        self._s = [0.0, 0.0]                                   # (u, u')
        self._e = 0.0                                          # previous error

    @classmethod
    def from_parameters(cls, params) -> 'TangentLoopShaping':
        """Build from ``dt``, ``valve_limit_V``, the rig calibration, the specimen's m, c, k,
        ``force_tangent_horizon_s`` and the ``hysteresis_*`` guesses."""
        from seft_msgs_py.parameters import spec
        from seft_ros.core.hysteresis import HystereticMember, MemberGuess
        dt = float(params['dt'])
        horizon = float(params.get('force_tangent_horizon_s',
                                   spec('force_tangent_horizon_s').default))
        member = HystereticMember(MemberGuess.from_parameters(params, predictor=False), dt)
        return cls(dt, float(params['valve_limit_V']), num=(controller_gain_V_per_N(params),),
                   den=specimen_denominator(params), member=member, horizon_s=horizon)

    @property
    def uses_motion(self) -> bool:
        """True: the tangent stiffness comes from the measured motion and force."""
        return True

    def frozen(self, rho: float) -> ForceServoController:
        """The linear controller this one is while ``rho`` stays at `rho` (a frozen tangent
        stiffness ``rho k``): ``C(s; rho)`` by Tustin at the same prewarped period, so that its
        :meth:`~ForceServoController.state_space` is this recursion's (the stability map's
        frozen-tangent linearizations)."""
        return ForceServoController(self.dt, self.valve_limit_V, self.design.num,
                                    (1.0, self._c1, self._w2 * float(rho)),
                                    prewarp_rad_s=math.sqrt(self._w2),
                                    kind=f'{self.kind} at rho = {rho:g}')

    def reset(self) -> None:
        """Zero the controller state (the member model keeps what it learnt)."""
        super().reset()
        self._s = [0.0, 0.0]
        self._e = 0.0
        self.rho = 1.0

    def step(self, reference_force_N: float, measured_force_N: float,
             velocity_m_s: float = 0.0, acceleration_m_s2: float = 0.0,
             displacement_m: float = 0.0) -> float:
        """Return the valve command [V] for one sample (see :meth:`ForceServoController.step`;
        the displacement [m] as well: the member's model needs the full measurement)."""
        member = self.member
        member.observe(displacement_m, velocity_m_s, acceleration_m_s2, measured_force_N)
        rho = member.tangent_ahead(self.horizon_s) / member.model.stiffness_N_per_m
        lo, hi = self.RHO_RANGE
        rho = lo if not rho > lo else (hi if rho > hi else rho)      # NaN: the lower bound
        self.rho = rho
        # trapezoidal step of u'' = g e - c1 u' - w2 rho u (module notes), 2x2 in closed form
        h, c1, w2 = self._h, self._c1, self._w2 * rho
        e = reference_force_N - measured_force_N
        u, du = self._s
        ge = h * self._g * (e + self._e)
        # (I + A h) s + B h (e + e_prev), then (I - A h)^-1
        p = u + h * du
        q = -w2 * h * u + (1.0 - c1 * h) * du + ge
        det = 1.0 + c1 * h + w2 * h * h
        u = ((1.0 + c1 * h) * p + h * q) / det
        du = (-w2 * h * p + q) / det
        self._s = [u, du]
        self._e = e
        lim = self.valve_limit_V
        if u > lim or u < -lim:
            self.saturated = True
            return lim if u > 0 else -lim
        self.saturated = False
        return u


class SaturationInterlock:
    """Loss-of-force-control interlock on the servo-valve command.

    Trips when the valve command was saturated in more than ``abort_fraction`` of the last
    ``window_s`` seconds of samples. A substructure EFT loop that went unstable with a
    saturating valve settles into a large high-frequency limit cycle (about 37 Hz on the
    calibrated servohydraulic rig) that need not reach the stroke or force limits; a force
    controller whose valve is pinned at its limit has lost control, and the run must stop
    (the role of the "error detectors" of commercial servo controllers).

    Parameters
    ----------
    dt : float > 0
        Control period [s].
    window_s : float > 0
        Sliding window [s].
    abort_fraction : float in (0, 1]
        Saturated fraction that trips the interlock (1: never trips).

    Raises
    ------
    ParameterError
        If a value is out of range.
    """

    def __init__(self, dt: float, window_s: float = 0.1, abort_fraction: float = 0.5):
        if not (dt > 0 and np.isfinite(dt)):
            raise ParameterError(f'parameter dt={dt!r}: expected float > 0')
        if not window_s > 0:
            raise ParameterError(f'parameter saturation_window_s={window_s!r}: expected > 0')
        if not 0 < abort_fraction <= 1:
            raise ParameterError(
                f'parameter saturation_abort_fraction={abort_fraction!r}: expected in (0, 1]')
        self.window = max(1, int(round(window_s / dt)))
        self.window_s = self.window * dt
        self.abort_fraction = float(abort_fraction)
        # the largest tolerated count, exact for fractions like 0.58 (0.58*50 = 28.999...)
        self._max_count = int(np.floor(self.abort_fraction * self.window + 1e-9))
        self._flags = [False] * self.window
        self._i = 0
        self._count = 0

    @classmethod
    def from_parameters(cls, params) -> 'SaturationInterlock':
        """Build from ``dt``, ``saturation_window_s`` and ``saturation_abort_fraction``."""
        return cls(float(params['dt']), float(params['saturation_window_s']),
                   float(params['saturation_abort_fraction']))

    def update(self, saturated: bool, time_s: float) -> str | None:
        """Record one sample; return a one-line abort reason when the interlock trips."""
        if not saturated and not self._count:
            return None             # a window of unsaturated samples stays one (the common case)
        flags, i = self._flags, self._i
        old = flags[i]
        flags[i] = saturated
        i += 1
        self._i = 0 if i == self.window else i
        if saturated is not old:
            self._count += int(saturated) - int(old)
        if self._count > self._max_count and self.abort_fraction < 1:
            return (f'force control lost at t={time_s:.3f} s: valve command saturated in '
                    f'{self._count}/{self.window} samples of the last {self.window_s:.3f} s')
        return None


#: ``reference_extrapolation`` values (:class:`ReferencePlayout`).
REFERENCE_EXTRAPOLATIONS = ('prediction', 'linear')
def prediction_window_steps(params) -> int:
    """The forces a real-time controller fits its late-force predictor to (``0``: linear
    extrapolation), from ``reference_extrapolation`` and ``dt``.

    Raises
    ------
    ParameterError
        ``reference_extrapolation`` not one of :data:`REFERENCE_EXTRAPOLATIONS`.
    """
    mode = params.get('reference_extrapolation', 'prediction')
    if mode not in REFERENCE_EXTRAPOLATIONS:
        raise ParameterError(f'parameter reference_extrapolation={mode!r}: expected one of '
                             + ', '.join(repr(m) for m in REFERENCE_EXTRAPOLATIONS))
    return window_steps(float(params['dt'])) if mode == 'prediction' else 0


class ReferencePlayout:
    """The reference force a real-time force servo controller acts on at each step.

    In real time the controller never waits (:mod:`seft_ros.nodes.force_servo_controller`):
    at step ``k`` it acts on ``f_r[k - m]`` (``m`` = ``playout_steps``, the network delay in
    steps; 0 on one host). When that force has not arrived (the builder or its host was late)
    the step is **stale**. Holding the newest force then is a step error of ``f_r'`` times
    the lateness; with ``model`` the force is the force-loop inverse's command, rich in high
    frequencies, and each held step kicks the specimen. Extrapolated linearly from the two
    newest (at most ``extrapolate_steps`` beyond the newest, then held there) the error drops
    to ``f_r''`` times the lateness squared over 2.

    With ``prediction_window`` forces of history (``reference_extrapolation: prediction``,
    the default) the force is predicted instead by a linear predictor of order
    :data:`~seft_msgs_py.prediction.PREDICTION_ORDER` fitted, at the stale step, to the last
    `prediction_window` forces by least squares (the autocorrelation-free *covariance
    method*, with a ridge of :data:`~seft_msgs_py.prediction.PREDICTION_RIDGE`;
    :class:`~seft_msgs_py.prediction.SampleHistory`), unless its one-step residual over the
    window is no smaller
    than linear extrapolation's. A reference force is dominated by the lightly damped
    modes of the test, which such a predictor follows exactly (an AR(2) predicts a sinusoid
    without error). On the real-time references of a 32 Hz, 0.5 % specimen at alpha 1
    (valve_2nd_order, ``model`` and ``adaptive``) and of a two-story structure, its one-step
    error was 0.16-1.7 % of the force's RMS against 3.7-11.7 % extrapolated linearly; the
    stale steps of four real-time runs of that specimen (8-243 steps of 5000) replayed in
    process cost 4.0-8.8 % in x extrapolated linearly and 1.0-2.2 % predicted (0.48-0.68 %
    with none). The fit costs 53 us at a stale step only (median, an idle host); every other
    step stores its force (0.35 us).

    Measured (benchmarks/stale_reference.py: the two-pier bridge of ``config/two_piers.yaml``
    with ``model``; the stale steps of three real-time runs on a loaded 2-core host, 0.5-1.4 %
    of the steps, replayed in process): held, the replay reproduces the runs' displacement
    NRMS of pier_a (0.25 / 0.64 / 1.10 % against 0.25 / 0.66 / 1.22 % measured), so late
    forces are most of a real-time run's error there; extrapolated, 0.17-0.21 % (0.165 % with
    no stale step). A stale step every 37th on each pier (2.7 %): held 0.83 / 0.92 / 0.82 %
    per DOF, extrapolated linearly 0.21 / 0.24 / 0.19 %, predicted 0.164 / 0.190 / 0.154 %
    (lockstep 0.162 / 0.187 / 0.153 %); the study's test at alpha 1.5 the same way: held
    1.13 %, linearly 0.55 %, predicted 0.578 % (lockstep 0.577 %).

    Parameters
    ----------
    playout_steps : int >= 0
        ``m``: step ``k`` acts on ``f_r[k - m]`` (``f_r[0]`` before step ``m``).
    extrapolate_steps : int >= 0
        The longest extrapolation beyond the newest force [steps] (0: hold the newest, as a
        zero-order hold).
    prediction_window : int >= 0
        Forces the predictor is fitted to (:func:`prediction_window_steps`; 0: extrapolate
        linearly; fewer than ``4 PREDICTION_ORDER`` are refused).

    Raises
    ------
    ParameterError
        A negative `playout_steps` or `extrapolate_steps`, or a `prediction_window` too
        short.

    References
    ----------
    Extrapolating a late command from the last ones: M. Nakashima and N. Masaoka (1999),
    Real-time on-line test for MDOF systems, Earthquake Engng Struct. Dyn. 28(4), 393-420
    (the extrapolation of the command between solver steps). Linear prediction by least
    squares: J. Makhoul (1975), Linear prediction: a tutorial review, Proc. IEEE 63(4),
    561-580 (the covariance method, Sec. III).
    """

    def __init__(self, playout_steps: int = 0, extrapolate_steps: int = 0,
                 prediction_window: int = 0):
        if int(playout_steps) < 0:
            raise ParameterError(f'playout steps {playout_steps!r}: expected >= 0')
        if int(extrapolate_steps) < 0:
            raise ParameterError('parameter reference_extrapolation_steps='
                                 f'{extrapolate_steps!r}: expected >= 0')
        window = int(prediction_window)
        if window and window < 4 * PREDICTION_ORDER:
            raise ParameterError(f'prediction window {prediction_window!r}: expected 0 or at '
                                 f'least {4 * PREDICTION_ORDER} forces')
        self.playout_steps = int(playout_steps)
        self.extrapolate_steps = int(extrapolate_steps)
        self.prediction_window = window
        self._forces: dict[int, float] = {}     # step -> f_r [N], the ones still needed
        self._replay_pending: list[tuple[int, float]] = []   # replay: computed, not arrived
        self._newest = (-1, 0.0)                # (step, f_r) of the newest force received
        self._before = (-1, 0.0)                # and of the one before it
        #: how many stale forces the predictor gave (the others: linear extrapolation)
        self.predicted = 0
        self._history = SampleHistory(window) if window else None

    def receive(self, step: int, force_N: float) -> None:
        """A reference force arrived (any order; a repeat replaces it)."""
        self._forces[step] = force_N
        newest, before = self._newest[0], self._before[0]
        if step > newest:
            self._before, self._newest = self._newest, (step, force_N)
        elif step == newest:
            self._newest = (step, force_N)
        elif step >= before:
            self._before = (step, force_N)
        if self._history is not None:
            self._history.store(step, force_N)

    def has_due(self, k: int) -> bool:
        """Whether the force step `k` acts on has arrived."""
        return max(k - self.playout_steps, 0) in self._forces

    def due(self, k: int) -> tuple[float, bool, int]:
        """The force step `k` acts on, and forget those no later step needs.

        Returns
        -------
        force_N : float
            ``f_r[k - m]``; when it has not arrived, its prediction or extrapolation (class
            notes) or, before two forces have arrived, the newest (0 before any).
        stale : bool
            ``f_r[k - m]`` had not arrived.
        source_step : int
            The step of the newest force used (-1: none yet).
        """
        due = max(k - self.playout_steps, 0)
        forces = self._forces
        value = forces.get(due)
        stale = value is None
        if stale:
            (j1, f1), (j0, f0) = self._newest, self._before
            value, source = f1, j1
            if j0 >= 0 and j1 < due and self.extrapolate_steps:
                ahead = min(due - j1, self.extrapolate_steps)
                predicted = (self._history.predict(j1, ahead) if self._history is not None
                             else None)
                if predicted is None:
                    value = f1 + ahead * (f1 - f0) / (j1 - j0)
                else:
                    value = predicted
                    self.predicted += 1
        else:
            source = due
        # f_r[0] serves steps 0..m; after that each force serves one step
        done = due if k >= self.playout_steps else due - 1
        for j in [j for j in forces if j <= done]:
            del forces[j]
        return value, stale, source

    def replay(self, k: int, force_N: float, late: int = 0) -> float:
        """One step of an in-process replay of a real-time run; returns the force acted on
        [N] (:meth:`due`'s).

        The force of step `k` is computed now; the controller acts on step `k` holding the
        forces up to step ``k - late`` (``late`` 0: in time; 1: the force of `k` arrives
        just after; ``d > 1``: the builder was ``d`` steps behind, as a host stall leaves
        it). The others arrive at later steps, in order; a force once received stays
        (``late`` may fall by more than one a step, never un-receive one). ``True`` is 1.
        """
        pending = self._replay_pending
        pending.append((k, force_N))
        limit = k - int(late)
        while pending and pending[0][0] <= limit:
            self.receive(*pending.pop(0))
        return self.due(k)[0]
