"""Online instability monitor: growing high-frequency oscillation of the measured force."""

import math

import numpy as np
from scipy import signal

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.parameters import spec
from seft_ros.core.controller import DiscreteFilter

__all__ = ['InstabilityMonitor', 'open_loop_identification']


def open_loop_identification(params) -> bool:
    """Whether `params` describe an open-loop identification run.

    Parameters
    ----------
    params : mapping
        Run parameters (``excitation`` and ``excitation_input`` default to ``'none'`` and
        ``'reference_force'`` when absent).

    Returns
    -------
    bool
        True when an excitation plays on the valve (``excitation_input: valve_command``):
        the force controller is bypassed and the reference force drives nothing.
    """
    return (params.get('excitation', 'none') != 'none'
            and params.get('excitation_input', 'reference_force') == 'valve_command')


class InstabilityMonitor:
    """Detects the high-frequency oscillation of an unstable substructure EFT loop.

    The measured force is split by 2nd-order Butterworth filters (``scipy.signal.butter``)
    at ``cutoff_hz`` into a high band ``f_hf`` (the loop's unstable mode: about 37 Hz on the
    calibrated servohydraulic rig, near Nyquist on the delay rig) and a low band ``f_lf``
    (the earthquake response). Their running RMS values ``r_hf``, ``r_lf`` are exponential
    moving averages of the squares with time constant ``window_s``. The monitor trips when

        r_hf > threshold * (r_lf + 0.05 * F_g + floor_N)

    where ``F_g = (1 + alpha) m max|xg''|`` is the largest ground-motion force seen so far and
    ``floor_N`` an absolute floor; both keep sensor noise from tripping it at the quiet start
    of a record (white load-cell noise puts about 90 % of its power above 25 Hz).

    Calibration (``benchmarks/monitor_margin.py``): over the synthetic default, the Kobe
    KJM000/KJM090 and El Centro records, on both rigs, alpha = 0-1.2 (stable), the largest
    ratio ``r_hf / (r_lf + 0.05 F_g)`` of a stable run was 0.66; every unstable run reached
    1.5 or more. The default threshold 1.0 sits between them. With the later defaults (Eq.
    3.1 read in V/lbf, ground preview on) the margins narrowed: stable runs reach 0.69-0.80,
    unstable ones 1.44 or more (``tests/seft_ros/core/test_monitor.py``).

    Parameters
    ----------
    dt : float > 0
        Control period [s].
    cutoff_hz : float > 0
        Band split [Hz]; must be below the Nyquist frequency.
    window_s : float > 0
        Time constant of the running RMS [s].
    threshold : float >= 0
        Trip ratio (0 disables the monitor).
    floor_N : float >= 0
        Absolute floor of the comparison [N] (default 50 N: ten times the noise of a
        typical 22 kN load cell).

    Raises
    ------
    ParameterError
        If a value is out of range.
    """

    def __init__(self, dt: float, cutoff_hz: float = 25.0, window_s: float = 0.2,
                 threshold: float = 1.0, floor_N: float = 50.0):
        if not cutoff_hz > 0:
            raise ParameterError(f'parameter monitor_cutoff_hz={cutoff_hz!r}: expected > 0')
        if not cutoff_hz < 0.5 / dt and cutoff_hz != spec('monitor_cutoff_hz').default:
            raise ParameterError(f'parameter monitor_cutoff_hz={cutoff_hz!r}: expected > 0 '
                                 f'and below the Nyquist frequency {0.5 / dt:g} Hz')
        if not cutoff_hz < 0.5 / dt:          # the default cut-off: dt is what the user set
            raise ParameterError(f'parameter dt={dt!r}: the sample period is too long for the '
                                 f'instability monitor, whose band split monitor_cutoff_hz='
                                 f'{cutoff_hz:g} Hz must lie below the Nyquist frequency '
                                 f'1/(2 dt) = {0.5 / dt:g} Hz; expected dt < '
                                 f'{0.5 / cutoff_hz:g} s')
        if not window_s > 0:
            raise ParameterError(f'parameter monitor_window_s={window_s!r}: expected > 0')
        if not threshold >= 0:
            raise ParameterError(f'parameter monitor_threshold={threshold!r}: expected >= 0')
        if not floor_N >= 0:
            raise ParameterError(f'parameter monitor_floor_N={floor_N!r}: expected >= 0')
        self.floor_N = float(floor_N)
        self.dt = float(dt)
        self.threshold = float(threshold)
        self._hp = DiscreteFilter(*signal.butter(2, cutoff_hz, 'highpass', fs=1.0 / dt))
        self._lp = DiscreteFilter(*signal.butter(2, cutoff_hz, 'lowpass', fs=1.0 / dt))
        self._beta = float(np.exp(-dt / window_s))
        self._ms_hf = 0.0
        self._ms_lf = 0.0
        self.ground_force_scale_N = 0.0
        self.ratio = 0.0

    @classmethod
    def from_parameters(cls, params) -> 'InstabilityMonitor':
        """Build from ``dt`` and the ``monitor_*`` parameters.

        In an open-loop identification run (``excitation`` other than ``'none'`` with
        ``excitation_input: valve_command``) the monitor is built disarmed (threshold 0): the
        loop it guards (measured acceleration, reference force, force controller) is open
        there, since the valve plays the excitation and the reference force drives nothing,
        so no oscillation can grow through it; and the broadband valve excitation puts force
        above the cut-off by design (a healthy default rig reaches 4-10 times the threshold
        with 0.05-0.5 V of noise). The run's amplitude limits guard it instead: the rig's
        ``stroke_limit_m`` and ``force_limit_N``. A closed-loop identification run
        (``excitation_input: reference_force``) keeps the monitor: the excitation is the
        ground-motion term of the reference force, so the comparison scales with it (healthy
        runs up to 0.68 of the threshold at alpha 0-1, an unstable alpha = 1.5 trips).

        Parameters
        ----------
        params : mapping
            Resolved parameters: ``dt``, ``monitor_cutoff_hz``, ``monitor_window_s``,
            ``monitor_threshold``, ``monitor_floor_N`` and, if present, ``excitation`` and
            ``excitation_input``.

        Returns
        -------
        InstabilityMonitor

        Raises
        ------
        ParameterError
            A value out of range (the message names the parameter).
        """
        threshold = float(params['monitor_threshold'])
        if open_loop_identification(params):
            threshold = 0.0
        return cls(float(params['dt']), float(params['monitor_cutoff_hz']),
                   float(params['monitor_window_s']), threshold,
                   float(params['monitor_floor_N']))

    def update(self, measured_force_N: float, ground_force_N: float,
               time_s: float) -> str | None:
        """Add one sample; return a one-line reason when the oscillation is detected.

        Parameters
        ----------
        measured_force_N : float
            Load-cell force of the sample [N].
        ground_force_N : float
            Ground-motion part of the reference force, ``-(1+alpha) m xg''`` [N].
        time_s : float
            Sample time [s], for the message.
        """
        x = measured_force_N
        # the two Butterworth sections (DiscreteFilter.step of a biquad, written out)
        z = self._hp._z
        b0, b1, b2, a1, a2 = self._hp._biquad
        hf = b0 * x + z[0]
        z[0] = b1 * x - a1 * hf + z[1]
        z[1] = b2 * x - a2 * hf
        z = self._lp._z
        b0, b1, b2, a1, a2 = self._lp._biquad
        lf = b0 * x + z[0]
        z[0] = b1 * x - a1 * lf + z[1]
        z[1] = b2 * x - a2 * lf
        b = self._beta
        ms_hf = self._ms_hf = b * self._ms_hf + (1.0 - b) * hf * hf
        ms_lf = self._ms_lf = b * self._ms_lf + (1.0 - b) * lf * lf
        scale = abs(ground_force_N)
        if scale > self.ground_force_scale_N:
            self.ground_force_scale_N = scale
        floor = math.sqrt(ms_lf) + 0.05 * self.ground_force_scale_N + self.floor_N
        self.ratio = math.sqrt(ms_hf) / floor if floor > 0 else 0.0
        if self.threshold > 0 and self.ratio > self.threshold:
            return (f'unstable at t={time_s:.3f} s: high-frequency oscillation of the measured '
                    f'force, RMS above the cut-off {self.ratio:.2f} x the response band '
                    f'(threshold {self.threshold:g})')
        return None
