"""The force servo controller: the reference study's loop-shaping controller, discretized."""

from dataclasses import dataclass

import numpy as np
from scipy import signal

from seft_msgs_py.calibration import CALIBRATIONS, DEFAULT_CALIBRATION, controller_gain_V_per_N
from seft_msgs_py.errors import ParameterError

__all__ = ['DiscreteFilter', 'ForceServoController', 'SaturationInterlock', 'LOOP_SHAPING_NUM',
           'LOOP_SHAPING_DEN']

#: Numerator of C_f(s) = 37 / (s^2 + 17.14 s + 4002) [V/N] (paper Eq. 3.1) in the default
#: reading, V/lbf: 37/4.448 = 8.318 V/N (:mod:`seft_msgs_py.calibration`; 'si': 37 V/N).
LOOP_SHAPING_NUM = (CALIBRATIONS[DEFAULT_CALIBRATION].controller_gain_V_per_N,)
#: Denominator of C_f(s) (paper Eq. 3.1).
LOOP_SHAPING_DEN = (1.0, 17.14, 4002.0)


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


class ForceServoController:
    """Loop-shaping force controller ``C_f(s) = 37/(s^2 + 17.14 s + 4002)`` at period ``dt``.

    The valve command is ``u[k] = sat(C_f(z) e[k])`` with the force error
    ``e[k] = f_r[k] - f_m[k]`` [N] and the saturation ``|u| <= valve_limit_V`` [V]. The
    gain 37 is in volts per unit of force of the rig calibration (parameter
    ``rig_calibration``, :mod:`seft_msgs_py.calibration`): V/lbf by default, 37/4.448 V/N.

    Discretization: Tustin (bilinear) with frequency prewarping at the controller's resonance
    ``w0 = sqrt(den[2])`` (sqrt(4002) rad/s = 10.07 Hz), done by
    ``scipy.signal.cont2discrete(method='bilinear')`` at the prewarped period
    ``2*tan(w0*dt/2)/w0``. Why: the controller's lightly damped poles are there to cancel the
    control-structure-interaction zero at the specimen's natural frequency, so they must land
    exactly there (prewarping makes the discrete response exact at w0); Tustin maps the stable
    poles to stable discrete poles and adds no phase lag (measured: within 1.7 % in magnitude
    and 0.1 deg in phase of the continuous controller up to 25 Hz at dt = 2 ms), whereas a
    zero-order-hold or Euler emulation adds about half a sample of lag, which the 12 Hz
    crossover cannot spare. The controller has no integrator, so saturating its output cannot
    wind it up.

    Parameters
    ----------
    dt : float > 0
        Control period [s].
    valve_limit_V : float > 0
        Valve command saturation [V] (reference rig: 10 V).
    num, den : sequence of float
        Continuous controller coefficients [V/N] (default: paper Eq. 3.1 in V/lbf).

    Raises
    ------
    ParameterError
        If ``dt <= 0`` or ``valve_limit_V <= 0``.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eq. 3.1, Figs. 3-4;
    N. Nakata (2012), Effective force testing using a robust loop shaping controller.
    """

    def __init__(self, dt: float, valve_limit_V: float = 10.0,
                 num=LOOP_SHAPING_NUM, den=LOOP_SHAPING_DEN):
        if not dt > 0:
            raise ParameterError(f'parameter dt={dt!r}: expected float > 0')
        if not valve_limit_V > 0:
            raise ParameterError(f'parameter valve_limit_V={valve_limit_V!r}: expected float > 0')
        self.dt = float(dt)
        self.valve_limit_V = float(valve_limit_V)
        w0 = float(np.sqrt(den[-1] / den[0]))
        prewarped_dt = 2.0 * np.tan(w0 * self.dt / 2.0) / w0
        bz, az, _ = signal.cont2discrete((num, den), prewarped_dt, method='bilinear')
        self.design = ControllerDesign(tuple(num), tuple(den), self.dt,
                                       f'bilinear, prewarped at {w0:.4g} rad/s')
        self.bz = np.ravel(bz)
        self.az = np.ravel(az)
        self._filter = DiscreteFilter(self.bz, self.az)
        self.saturated = False

    @classmethod
    def from_parameters(cls, params) -> 'ForceServoController':
        """Build from the parameter schema (``dt``, ``valve_limit_V``, ``rig_calibration``)."""
        return cls(float(params['dt']), float(params['valve_limit_V']),
                   num=(controller_gain_V_per_N(params),))

    def continuous(self) -> signal.TransferFunction:
        """The continuous controller C_f(s) [V/N]."""
        return signal.TransferFunction(self.design.num, self.design.den)

    def discrete(self) -> signal.TransferFunction:
        """The discretized controller C_f(z) [V/N] with ``dt``."""
        return signal.TransferFunction(self.bz, self.az, dt=self.dt)

    def reset(self) -> None:
        """Zero the controller state."""
        self._filter.reset()
        self.saturated = False

    def step(self, reference_force_N: float, measured_force_N: float) -> float:
        """Return the valve command [V] for one sample of reference and measured force [N]."""
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
        if u > lim:
            self.saturated = True
            return lim
        if u < -lim:
            self.saturated = True
            return -lim
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
