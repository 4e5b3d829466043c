"""The force loop's plant as data: valve command to measured force and motion, discrete at dt.

A lab's actuator is not seft's. Everything that reasons about the force loop (the force
controller's design, the compensators' force-loop inverse, the stability map, the pre-run
guard and its robustness margin, ``seft identify``'s comparison) takes one object,
:class:`PlantModel`: the sampled plant from the valve command ``u`` [V] to the measured
force, displacement, velocity and acceleration of the specimen, with the specimen in the
loop (its control-structure interaction is in the plant), linear, discrete at the control
period ``dt``, of any order::

    s[k+1] = A s[k] + B u[k]
    y[k]   = C s[k]          y = (f_m [N], x [m], v [m/s], a [m/s^2])     (OUTPUTS)

strictly proper (the sample of ``t_k`` does not depend on the command of step ``k``, the
timing of :class:`~seft_msgs_py.interface.Rig`), whole-step delays of the command as states.
It comes from one of three places:

- seft's simulated servohydraulic rig (``seft_plant_sim.servohydraulic.ServoHydraulicPlant``,
  a subclass that keeps the exact sampled model of that rig);
- identification from a lab's bags (``seft identify``:
  :mod:`seft_ros.analysis.plant_identification`);
- a model the lab writes (:meth:`PlantModel.from_mapping`: a state space or a transfer
  function, continuous or discrete, with a pure delay of the command), the ``plant_model``
  parameter or a ``plant_model:`` section of a configuration.

Each carries its uncertainty (:class:`PlantUncertainty`): how far the lab's actuator may be
from the model, as a relative bound on the force response.

Imports nothing of ROS. python-control is imported where it is used
(:meth:`PlantModel.to_lti`): the step loops use plain floats.

References
----------
K. J. Astrom and B. Wittenmark, Computer-Controlled Systems, 3rd ed., 1997, Ch. 2 (sampling
with a time delay), Sec. 7.4 (a delayed input as states).
S. J. Dyke, B. F. Spencer Jr., P. Quast and M. K. Sain, Role of control-structure interaction
in protective system design, J. Eng. Mech. 121(2), 1995, 322-338.
"""

from dataclasses import dataclass
import json
import math
from typing import Any, Mapping

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.sampling import split_delay, zoh

__all__ = ['OUTPUTS', 'PlantModel', 'PlantUncertainty', 'Specimen', 'LoopResponses',
           'sample_continuous', 'hold_factor', 'controller_response', 'schur_response',
           'parse_plant',
           'MOTION_OUTPUTS', 'MAX_IO_DELAY_STEPS']

#: The outputs of a :class:`PlantModel`, rows of its ``c``, in this order.
OUTPUTS = ('force_N', 'displacement_m', 'velocity_m_s', 'acceleration_m_s2')
#: The motion outputs, which a model of the force alone derives from its specimen.
MOTION_OUTPUTS = OUTPUTS[1:]
_FORMS = ('state_space', 'transfer_function')
#: The longest pure delay of the command a lab's model may state (``io_delay_s``), in steps of
#: the run's ``dt``. Each step of it is a state of the sampled model (a 2 s delay at 2 ms made
#: 1000 states, and ``seft design``'s frequency response on them wanted 50 GiB; at 50 steps
#: the design of a 6-state model takes 0.5 GB and 8 s), and the 'model' compensator inverts
#: the force loop to at most this many steps of delay (the largest
#: ``predictor_loop_delay_steps``): it could not compensate a longer one anyway.
MAX_IO_DELAY_STEPS = 50


@dataclass(frozen=True)
class Specimen:
    """The specimen in a plant's loop, ``m x'' + c x' + k x = f`` (paper Eq. 5.1).

    Attributes
    ----------
    mass_kg, damping_N_s_per_m, stiffness_N_per_m : float
        m [kg] > 0, c [N s/m] >= 0, k [N/m] > 0.
    """

    mass_kg: float
    damping_N_s_per_m: float
    stiffness_N_per_m: float

    @property
    def natural_frequency_hz(self) -> float:
        """``sqrt(k/m)/(2 pi)`` [Hz]: the plant's control-structure-interaction zero."""
        return math.sqrt(self.stiffness_N_per_m / self.mass_kg) / (2.0 * math.pi)

    @property
    def damping_ratio(self) -> float:
        """``c/(2 sqrt(k m))`` [-]."""
        return self.damping_N_s_per_m / (2.0 * math.sqrt(self.stiffness_N_per_m
                                                         * self.mass_kg))

    def polynomial(self) -> np.ndarray:
        """``[m, c, k]``: ``m s^2 + c s + k``, the force per displacement [N/m]."""
        return np.array([self.mass_kg, self.damping_N_s_per_m, self.stiffness_N_per_m])

    def mismatch(self, mass_kg: float, stiffness_N_per_m: float,
                 tolerance: float) -> tuple[float, float] | None:
        """How far a declared specimen lies from this one.

        Parameters
        ----------
        mass_kg, stiffness_N_per_m : float > 0
            The declared specimen's m [kg] and k [N/m].
        tolerance : float >= 0
            The relative difference within which the two agree.

        Returns
        -------
        tuple of float or None
            ``(m / self.mass_kg, k / self.stiffness_N_per_m)`` when either lies further than
            `tolerance` from 1, else None.
        """
        ratios = (mass_kg / self.mass_kg, stiffness_N_per_m / self.stiffness_N_per_m)
        if all(abs(r - 1.0) <= tolerance for r in ratios):
            return None
        return ratios

    def to_mapping(self) -> dict[str, float]:
        """``{'mass_kg': m, 'damping_N_s_per_m': c, 'stiffness_N_per_m': k}``."""
        return {'mass_kg': self.mass_kg, 'damping_N_s_per_m': self.damping_N_s_per_m,
                'stiffness_N_per_m': self.stiffness_N_per_m}

    @classmethod
    def from_mapping(cls, doc, *, where: str) -> 'Specimen':
        """From ``{mass_kg, damping_N_s_per_m, stiffness_N_per_m}``.

        Raises
        ------
        ParameterError
            An unknown key, a value missing, not a number or out of range (the message names
            `where`).
        """
        if not isinstance(doc, Mapping):
            raise ParameterError(f'{where}: expected a mapping with mass_kg, '
                                 'damping_N_s_per_m and stiffness_N_per_m')
        _known_fields(doc, ('mass_kg', 'damping_N_s_per_m', 'stiffness_N_per_m'), where)
        values = []
        for key, positive in (('mass_kg', True), ('damping_N_s_per_m', False),
                              ('stiffness_N_per_m', True)):
            v = doc.get(key)
            ok = (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                  and (v > 0 if positive else v >= 0))
            if not ok:
                raise ParameterError(f'{where}.{key}={v!r}: expected a number '
                                     + ('> 0' if positive else '>= 0'))
            values.append(float(v))
        return cls(*values)


@dataclass(frozen=True)
class PlantUncertainty:
    """How far the true plant may be from a :class:`PlantModel`.

    An unstructured multiplicative bound on the force response ``P`` (valve command to
    measured force): the true plant is ``P (1 + Delta)`` with ``|Delta(f)| <= relative`` in
    ``band_hz`` (Doyle, Francis and Tannenbaum 1992, Ch. 4: the robust-stability test of such
    a set is ``|T_u(f)| relative < 1`` with ``T_u`` the closed loop seen at the plant's
    input).

    Attributes
    ----------
    relative : float >= 0
        The bound [-] (0: not stated).
    band_hz : (float, float)
        Where it holds [Hz].
    note : str
        Where it comes from (an identification's fit error and coherence, a lab's statement).
    frequency : float >= 0
        The relative standard error of the model's lightly damped frequencies, its
        control-structure-interaction zero foremost (0: not stated) [-].
    peak_force_N, peak_velocity_m_s : float >= 0
        The largest measured force [N] and piston velocity [m/s] of the run the model was
        identified from (0: not stated): a linear model of a nonlinear actuator (friction,
        orifice flow) holds near the level it was identified at, and the stability guard
        gives no verdict on a test that plans far more
        (:data:`seft_ros.core.stability.MAX_LEVEL_EXTRAPOLATION`).
    """

    relative: float = 0.0
    band_hz: tuple = (0.0, math.inf)
    note: str = ''
    frequency: float = 0.0
    peak_force_N: float = 0.0
    peak_velocity_m_s: float = 0.0

    def to_mapping(self) -> dict[str, Any]:
        """``{'relative', 'band_hz', 'note', 'frequency'}`` and the identified peaks when
        stated (an infinite band end as None)."""
        doc = {'relative': float(self.relative),
               'band_hz': [float(b) if math.isfinite(b) else None for b in self.band_hz],
               'note': self.note, 'frequency': float(self.frequency)}
        if self.peak_force_N or self.peak_velocity_m_s:
            doc.update(peak_force_N=float(self.peak_force_N),
                       peak_velocity_m_s=float(self.peak_velocity_m_s))
        return doc

    @classmethod
    def from_mapping(cls, doc, *, where: str) -> 'PlantUncertainty':
        """From ``{relative, band_hz, note, frequency, peak_force_N, peak_velocity_m_s}``
        (each optional).

        Raises
        ------
        ParameterError
            An unknown key, a value not a number or out of range.
        """
        if not isinstance(doc, Mapping):
            raise ParameterError(f'{where}: expected a mapping with relative (and band_hz, '
                                 'note)')
        _known_fields(doc, ('relative', 'band_hz', 'note', 'frequency', 'peak_force_N',
                            'peak_velocity_m_s'), where)
        rel = doc.get('relative', 0.0)
        if isinstance(rel, bool) or not isinstance(rel, (int, float)) \
                or not (math.isfinite(rel) and rel >= 0):
            raise ParameterError(f'{where}.relative={rel!r}: expected a number >= 0')
        band = doc.get('band_hz', [0.0, None])
        if not (isinstance(band, (list, tuple)) and len(band) == 2):
            raise ParameterError(f'{where}.band_hz={band!r}: expected [low, high] in Hz')
        lo = 0.0 if band[0] is None else band[0]
        hi = math.inf if band[1] is None else band[1]
        if not all(isinstance(b, (int, float)) and not isinstance(b, bool) for b in (lo, hi)) \
                or not 0 <= lo < hi:
            raise ParameterError(f'{where}.band_hz={band!r}: expected 0 <= low < high')
        freq = doc.get('frequency', 0.0)
        if isinstance(freq, bool) or not isinstance(freq, (int, float)) \
                or not (math.isfinite(freq) and freq >= 0):
            raise ParameterError(f'{where}.frequency={freq!r}: expected a number >= 0')
        peaks = []
        for name in ('peak_force_N', 'peak_velocity_m_s'):
            v = doc.get(name, 0.0)
            if isinstance(v, bool) or not isinstance(v, (int, float)) \
                    or not (math.isfinite(v) and v >= 0):
                raise ParameterError(f'{where}.{name}={v!r}: expected a number >= 0 (0: not '
                                     'stated)')
            peaks.append(float(v))
        return cls(float(rel), (float(lo), float(hi)), str(doc.get('note', '')), float(freq),
                   *peaks)


class LoopResponses:
    """Impulse responses of a closed force loop (reference force ``f_r = delta[j]``).

    Attributes
    ----------
    sampled : ndarray, shape (n,)
        The measured force at ``t_j`` [N/N] (what closes the loop).
    step_average : ndarray, shape (n,)
        ``(1/dt) int_{t_j}^{t_j+1} f dt`` [N/N]: the force the specimen integrates over a
        step, which the compensators' force-loop inverse aims at.
    """

    __slots__ = ('sampled', 'step_average')

    def __init__(self, sampled, step_average):
        self.sampled = sampled
        self.step_average = step_average

    def __iter__(self):
        return iter((self.sampled, self.step_average))


def hold_factor(freqs_hz, dt: float) -> np.ndarray:
    """Step average of a sampled sinusoid: ``(z - 1)/(j omega dt)`` at ``z = e^{j omega dt}``.

    The average of ``e^{j omega t}`` over ``[t_k, t_k + dt]`` is ``e^{j omega t_k}`` times
    this (exact for a sinusoid; 1 at 0 Hz).

    Parameters
    ----------
    freqs_hz : array_like, shape (nf,)
    dt : float > 0
        Sample period [s].

    Returns
    -------
    ndarray of complex, shape (nf,)
    """
    omega_dt = 2.0 * np.pi * np.asarray(freqs_hz, dtype=float) * float(dt)
    out = np.ones(omega_dt.shape, dtype=complex)
    nz = omega_dt != 0
    out[nz] = (np.exp(1j * omega_dt[nz]) - 1.0) / (1j * omega_dt[nz])
    return out


def controller_response(controller, freqs_hz) -> np.ndarray:
    """The force error path ``C_e(e^{j omega dt})`` of a discrete controller [V/N].

    Parameters
    ----------
    controller : object with ``bz``, ``az`` (descending powers of z, the convention of
        ``scipy.signal.lfilter`` in powers of ``z^-1``) and ``dt`` [s]
    freqs_hz : array_like, shape (nf,)

    Returns
    -------
    ndarray of complex, shape (nf,)
    """
    b = np.atleast_1d(np.asarray(controller.bz, dtype=float))
    a = np.atleast_1d(np.asarray(controller.az, dtype=float))
    zinv = np.exp(-2j * np.pi * np.asarray(freqs_hz, dtype=float) * float(controller.dt))
    return np.polyval(b[::-1], zinv) / np.polyval(a[::-1], zinv)


def schur_response(a, b, c, z) -> tuple[np.ndarray, float]:
    """``c (zI - a)^-1 b`` at many points ``z``, from one complex Schur form of ``a``.

    ``a`` is balanced first (``scipy.linalg.matrix_balance``, scaling only: ``D^-1 a D``
    with ``D`` a diagonal of powers of 2, exact in floating point; ``b / D``, ``c D``), then
    ``a = U T U^H`` (``scipy.linalg.schur``, complex output) and ``(z - T) y = U^H b`` by
    back substitution, every point at once: O(n^2) per point against O(n^3) for a solve per
    point (30 times less on 8,000 frequencies of a plant), and right for a defective ``a``
    (the shift registers of a delay), where a sum over modes is not. Golub & Van Loan,
    *Matrix Computations*, 4th ed., sections 7.5.7 (balancing) and 7.6 (the Schur form for
    ``(zI - a)^-1`` at many shifts).

    Why balanced: a test loop on a lab's plant in physical units (pressures, flows) had a
    norm of 3.2e6 and ``zI - a`` a condition number of 2.6e17 at 0.5-2 Hz; unbalanced, the
    response there was 0.6-1 % off a direct solve and moved by up to 0.2 % with the plant's
    gain off by 1e-13, its predicted test errors by up to 10 x (and the force-loop design's
    choice of inverse with them); balanced (scales
    6e-5 to 2048, condition 2e7), it agrees with the solve to 1e-10.

    Parameters
    ----------
    a : array_like, shape (n, n)
        State matrix.
    b : array_like, shape (n,)
        Input vector.
    c : array_like, shape (n,)
        Output row.
    z : array_like of complex, shape (nz,)
        Points (``e^{j 2 pi f dt}`` for a discrete system's frequency response).

    Returns
    -------
    response : ndarray of complex, shape (nz,)
        ``c (zI - a)^-1 b``; inf or nan at an eigenvalue of ``a`` (with numpy's divide
        warning: the caller's ``np.errstate`` decides).
    radius : float
        The spectral radius of ``a`` (the largest ``|T_ii|``).

    Raises
    ------
    ValueError
        ``a`` not square, or the sizes of ``b`` and ``c`` not its order (numpy's and
        scipy's own errors).
    """
    from scipy.linalg import matrix_balance, schur

    balanced, (scale, _) = matrix_balance(np.asarray(a, dtype=float), permute=False,
                                          separate=True)
    tri, unitary = schur(balanced, output='complex')
    b_t = unitary.conj().T @ (np.asarray(b, dtype=float) / scale)
    c_t = (np.asarray(c, dtype=float) * scale) @ unitary
    z = np.asarray(z)
    n = tri.shape[0]
    y = np.zeros((z.shape[0], n), dtype=complex)
    for i in range(n - 1, -1, -1):
        y[:, i] = (b_t[i] + y[:, i + 1:] @ tri[i, i + 1:]) / (z - tri[i, i])
    return y @ c_t, float(np.max(np.abs(np.diag(tri))))

def sample_continuous(a, b, c, dt: float, delay_s: float = 0.0):
    """Sample a continuous plant exactly (zero-order hold) with a pure delay of its input.

    Parameters
    ----------
    a : ndarray, shape (n, n)
    b : ndarray, shape (n, 1)
    c : ndarray, shape (p, n)
        ``s' = a s + b u(t - delay_s)``, ``y = c s``.
    dt : float > 0
        Sample period [s].
    delay_s : float >= 0
        The input's delay [s], any value: ``delay_s = n dt + delta``.

    Returns
    -------
    A : ndarray, shape (n + m, n + m)
    B : ndarray, shape (n + m, 1)
    C : ndarray, shape (p, n + m)
        Delay-free discrete model with the past commands ``u[k-m], ..., u[k-1]`` as the last
        ``m`` states (``m = n + 1`` with a fractional remainder or ``n`` without).

    Notes
    -----
    Over ``[t_k, t_k+1)`` the input is ``u[k-n-1]`` for ``delta`` and ``u[k-n]`` for the rest
    (Astrom and Wittenmark 1997, Sec. 2.3): ``s[k+1] = Phi s[k] + Gamma_e u[k-n-1] + Gamma_l
    u[k-n]`` with ``Gamma_l = Gamma(dt - delta)``, ``Gamma_e = Phi(dt - delta) Gamma(delta)``
    (:func:`~seft_msgs_py.sampling.zoh`, ``scipy.signal.cont2discrete``).
    """
    a = np.atleast_2d(np.asarray(a, dtype=float))
    b = np.asarray(b, dtype=float).reshape(a.shape[0], 1)
    c = np.atleast_2d(np.asarray(c, dtype=float))
    ns = a.shape[0]
    n, delta = split_delay(float(delay_s), float(dt))
    phi, _ = zoh(a, b, dt)
    phi_rest, g_late = zoh(a, b, dt - delta)
    _, g_early = zoh(a, b, delta)
    g_early = (phi_rest @ g_early)[:, 0]
    g_late = g_late[:, 0]
    if delta == 0.0:                       # u[k-n] only: n past commands
        m = n
        big = np.zeros((ns + m, ns + m))
        bb = np.zeros((ns + m, 1))
        big[:ns, :ns] = phi
        if m == 0:
            bb[:ns, 0] = g_late
        else:
            big[:ns, ns] = g_late              # the oldest past command u[k-n]
    else:                                  # u[k-n-1] and u[k-n]: n + 1 past commands
        m = n + 1
        big = np.zeros((ns + m, ns + m))
        bb = np.zeros((ns + m, 1))
        big[:ns, :ns] = phi
        big[:ns, ns] = g_early
        if n >= 1:
            big[:ns, ns + 1] = g_late
        else:
            bb[:ns, 0] = g_late
    for i in range(m - 1):
        big[ns + i, ns + i + 1] = 1.0
    if m:
        bb[ns + m - 1, 0] = 1.0
    return big, bb, np.hstack([c, np.zeros((c.shape[0], m))])


def _delay_states(a, b, c, steps: int):
    """``(A, B, C)`` with `steps` whole steps of delay of the input, as states."""
    if steps <= 0:
        return a, b, c
    ns = a.shape[0]
    n = ns + steps
    big = np.zeros((n, n))
    bb = np.zeros((n, 1))
    big[:ns, :ns] = a
    big[:ns, ns] = b[:, 0]                 # the oldest past command drives the plant
    for i in range(steps - 1):
        big[ns + i, ns + i + 1] = 1.0
    bb[n - 1, 0] = 1.0
    return big, bb, np.hstack([c, np.zeros((c.shape[0], steps))])


class PlantModel:
    """The sampled plant from the valve command [V] to the measured force and motion.

    Parameters
    ----------
    a : array_like, shape (n, n)
    b : array_like, shape (n, 1)
    c : array_like, shape (4, n)
        Rows :data:`OUTPUTS`: force [N/V], displacement [m/V], velocity [m/s/V],
        acceleration [m/s^2/V] per state (``y[k] = c s[k]``).
    dt : float > 0
        Sample period [s].
    specimen : Specimen, optional
        The specimen in the loop (its poles are the force response's control-structure-
        interaction zeros).
    uncertainty : PlantUncertainty, optional
    source : str
        Where the model comes from (shown in the guard's and identify's lines).
    info : dict, optional
        Figures of its making (fit error, order, the bag), for the reports.

    Attributes
    ----------
    a, b, c, dt, specimen, uncertainty, source, info

    Raises
    ------
    ParameterError
        Shapes that do not fit, coefficients not finite, or ``dt <= 0``.

    Notes
    -----
    One object for the physical model of seft's rig, an identified model and a lab's own
    (python-control's one ``StateSpace`` for every system, :meth:`to_lti`).
    """

    def __init__(self, a, b, c, dt: float, *, specimen: Specimen | None = None,
                 uncertainty: PlantUncertainty | None = None, source: str = '',
                 info: dict | None = None):
        a = np.atleast_2d(np.asarray(a, dtype=float))
        b = np.asarray(b, dtype=float)
        c = np.atleast_2d(np.asarray(c, dtype=float))
        n = a.shape[0]
        if a.shape != (n, n) or b.size != n or c.shape != (len(OUTPUTS), n):
            raise ParameterError(f'plant model: expected a (n, n), b (n, 1) and c ({len(OUTPUTS)},'
                                 f' n), got {a.shape}, {b.shape}, {c.shape}')
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.all(np.isfinite(c))):
            raise ParameterError('plant model: expected finite coefficients')
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise ParameterError(f'plant model: dt={dt!r}: expected a period > 0 [s]')
        self.a = a
        self.b = b.reshape(n, 1)
        self.c = c
        self.dt = float(dt)
        self.specimen = specimen
        self.uncertainty = uncertainty or PlantUncertainty()
        self.source = str(source)
        self.info = dict(info or {})

    # -- shape ----------------------------------------------------------------------------

    @property
    def order(self) -> int:
        """Number of states n (the whole-step delays of the command included)."""
        return self.a.shape[0]

    def row(self, output: str) -> np.ndarray:
        """The row of ``c`` of one of :data:`OUTPUTS`, shape (n,).

        Raises
        ------
        ParameterError
            An unknown output name.
        """
        try:
            return self.c[OUTPUTS.index(output)]
        except ValueError:
            raise ParameterError(f'plant output {output!r}: expected one of '
                                 + ', '.join(OUTPUTS)) from None

    def augmented(self):
        """``(A, B, C)`` with C's rows ``(x, v, a, f_m)``: the rig of the stability analysis.

        Returns
        -------
        a : ndarray, shape (n, n)
        b : ndarray, shape (n, 1)
        c : ndarray, shape (4, n)
            Displacement, velocity, acceleration and measured force rows.
        """
        rows = [OUTPUTS.index(n) for n in ('displacement_m', 'velocity_m_s',
                                           'acceleration_m_s2', 'force_N')]
        return self.a, self.b, self.c[rows]

    def with_info(self, **info) -> 'PlantModel':
        """A copy with more ``info``."""
        out = PlantModel(self.a, self.b, self.c, self.dt, specimen=self.specimen,
                         uncertainty=self.uncertainty, source=self.source,
                         info=dict(self.info, **info))
        return out

    # -- responses -------------------------------------------------------------------------

    def frequency_response(self, freqs_hz, output: str = 'force_N') -> np.ndarray:
        """``c (zI - A)^-1 b`` at ``z = e^{j 2 pi f dt}`` for one output.

        Parameters
        ----------
        freqs_hz : array_like, shape (nf,)
            Frequencies [Hz] (below Nyquist ``1/(2 dt)``).
        output : str
            One of :data:`OUTPUTS`.

        Returns
        -------
        ndarray of complex, shape (nf,)
            [output unit / V].

        Raises
        ------
        ParameterError
            An output not in :data:`OUTPUTS`.

        Notes
        -----
        :func:`schur_response` (balanced, one Schur form for every frequency), as the test
        loop's response: on the family's plants of 2-50 Hz specimens it agrees with a solve
        per frequency to 1e-9 relative.
        """
        row = self.row(output)
        z = np.exp(2j * np.pi * np.atleast_1d(np.asarray(freqs_hz, dtype=float)) * self.dt)
        return schur_response(self.a, self.b[:, 0], row, z)[0]

    def impulse(self, n: int) -> np.ndarray:
        """Response to ``u = delta[k]`` (a 1 V command over the first step), shape (n, 4)."""
        out = np.zeros((int(n), len(OUTPUTS)))
        s = self.b[:, 0].copy()
        for k in range(1, int(n)):
            out[k] = self.c @ s
            s = self.a @ s
        return out

    def poles(self) -> np.ndarray:
        """Eigenvalues of ``A`` (in z)."""
        return np.linalg.eigvals(self.a)

    def zeros(self, output: str = 'force_N') -> np.ndarray:
        """The invariant zeros (in z) of one output's response: the finite generalized
        eigenvalues of the system pencil ``([[A, B], [C_i, 0]], [[I, 0], [0, 0]])``
        (Emami-Naeini and Van Dooren 1982; ``scipy.linalg.eigvals``).

        Raises
        ------
        ParameterError
            An output not in :data:`OUTPUTS`.
        """
        from scipy.linalg import eigvals
        n = self.order
        pencil = np.zeros((n + 1, n + 1))
        pencil[:n, :n], pencil[:n, n] = self.a, self.b[:, 0]
        pencil[n, :n] = self.row(output)
        ident = np.zeros((n + 1, n + 1))
        ident[:n, :n] = np.eye(n)
        with np.errstate(all='ignore'):
            w = eigvals(pencil, ident)
        return w[np.isfinite(w) & (np.abs(w) < 1e8)]

    def stable(self) -> bool:
        """Whether every pole lies strictly inside the unit circle."""
        return bool(np.all(np.abs(self.poles()) < 1.0))

    def loop_matrix(self, controller) -> np.ndarray:
        """The state matrix of the force loop closed by a discrete controller.

        The recursion of :meth:`loop_responses` with no reference: the force error
        ``e = -f``, the controller's inputs ``w = (e, v, a) = W s`` from the plant's state
        ``s`` (``W`` the rows -force, velocity, acceleration of ``c``), the command
        ``u = c_c x_c + d_c W s``, so that ``[s; x_c]`` steps by
        ``[[A + b d_c W, b c_c], [b_c W, a_c]]``.

        Parameters
        ----------
        controller : object with ``state_space()``
            As :meth:`loop_responses`.

        Returns
        -------
        ndarray, shape (n + n_c, n + n_c)
            The plant's n states first, then the controller's n_c; the loop is stable when
            every eigenvalue lies strictly inside the unit circle.
        """
        ac, bc, cc, dc = (np.atleast_2d(np.asarray(m, dtype=float))
                          for m in controller.state_space())
        w = np.vstack([-self.row('force_N'), self.row('velocity_m_s'),
                       self.row('acceleration_m_s2')])
        n, nc = self.order, ac.shape[0] if ac.size else 0
        m = np.zeros((n + nc, n + nc))
        m[:n, :n] = self.a + self.b @ (dc[:1] @ w)
        if nc:
            m[:n, n:] = self.b @ cc[:1]
            m[n:, :n] = bc @ w
            m[n:, n:] = ac
        return m

    def loop_radius(self, controller) -> float:
        """The spectral radius of :meth:`loop_matrix` (< 1: the closed force loop is stable)."""
        return float(np.max(np.abs(np.linalg.eigvals(self.loop_matrix(controller)))))

    def loop_responses(self, controller, n: int) -> LoopResponses:
        """Impulse responses of the force loop closed by a discrete controller.

        Parameters
        ----------
        controller : object with ``state_space()``
            ``(a_c, b_c, c_c, d_c)`` with the inputs ``(e, v, a)`` (force error [N], measured
            velocity [m/s] and acceleration [m/s^2]) and the valve command as output
            (:meth:`seft_ros.core.controller.ForceServoController.state_space`).
        n : int
            Number of samples.

        Returns
        -------
        LoopResponses
            ``sampled``: the measured force; ``step_average``: the held force that moves the
            specimen as the loop does (:meth:`held_force`, from the model's displacement and
            velocity), or without a specimen the force's step average through
            :func:`hold_factor` (exact for the sinusoidal steady state; the model knows the
            force only at the samples).
        """
        ac, bc, cc, dc = (np.atleast_2d(np.asarray(m, dtype=float))
                          for m in controller.state_space())
        a, b, c = self.a, self.b[:, 0], self.c
        fr, vr, ar = (c[OUTPUTS.index(k)] for k in ('force_N', 'velocity_m_s',
                                                     'acceleration_m_s2'))
        xr = c[OUTPUTS.index('displacement_m')]
        s = np.zeros(self.order)
        xc = np.zeros(ac.shape[0])
        sampled = np.zeros(int(n))
        motion = np.zeros((int(n) + 1, 2))
        for j in range(int(n)):
            f = float(fr @ s)
            sampled[j] = f
            motion[j] = float(xr @ s), float(vr @ s)
            w = np.array([(1.0 if j == 0 else 0.0) - f, motion[j, 1], float(ar @ s)])
            u = float(cc[0] @ xc + dc[0] @ w) if xc.size else float(dc[0] @ w)
            if xc.size:
                xc = ac @ xc + bc @ w
            s = a @ s + b * u
        motion[-1] = float(xr @ s), float(vr @ s)
        if self.specimen is None:
            return LoopResponses(sampled, step_average_of(sampled, self.dt))
        return LoopResponses(sampled, self.held_force(motion))

    def held_force(self, motion) -> np.ndarray:
        """The held force of each step that moves the specimen as the plant does.

        Parameters
        ----------
        motion : array_like, shape (n + 1, 2)
            Displacement [m] and velocity [m/s] at the samples.

        Returns
        -------
        ndarray, shape (n,)
            ``f[k] = (v[k+1] - (Phi s[k])_v) / Gamma_v`` [N]: the force held over
            ``[t_k, t_k+1)`` that takes the specimen (``m x'' + c x' + k x = f``, sampled
            with a zero-order hold) from ``s[k] = (x, v)[k]`` to ``v[k+1]`` (paper Eq. 5.1):
            what a compensator that models the specimen under held forces needs the force
            loop to deliver (the step-average force of a smooth force, to within its
            curvature).

        Raises
        ------
        ParameterError
            The plant has no specimen.
        """
        if self.specimen is None:
            raise ParameterError('plant model: no specimen to take the held force from')
        sp = self.specimen
        m, c, k = sp.mass_kg, sp.damping_N_s_per_m, sp.stiffness_N_per_m
        phi, gam = zoh(np.array([[0.0, 1.0], [-k / m, -c / m]]), np.array([[0.0], [1.0 / m]]),
                       self.dt)
        mo = np.asarray(motion, dtype=float)
        return (mo[1:, 1] - mo[:-1] @ phi[1]) / gam[1, 0]

    def to_lti(self):
        """The model as a python-control ``StateSpace`` (discrete, ``dt``), named signals.

        Returns
        -------
        control.StateSpace
            Input ``valve_command_V``; outputs :data:`OUTPUTS`.
        """
        import control
        return control.ss(self.a, self.b, self.c, np.zeros((len(OUTPUTS), 1)), self.dt,
                          inputs=['valve_command_V'], outputs=list(OUTPUTS))

    # -- serialization ---------------------------------------------------------------------

    def to_mapping(self) -> dict[str, Any]:
        """The model as a ``plant_model`` mapping (discrete state space), for YAML and JSON."""
        doc: dict[str, Any] = {
            'form': 'state_space', 'dt': self.dt,
            'a': self.a.tolist(), 'b': self.b[:, 0].tolist(),
            'c': {name: self.c[i].tolist() for i, name in enumerate(OUTPUTS)},
        }
        if self.specimen is not None:
            doc['specimen'] = self.specimen.to_mapping()
        if self.uncertainty.relative > 0 or self.uncertainty.note or self.uncertainty.frequency:
            doc['uncertainty'] = self.uncertainty.to_mapping()
        if self.source:
            doc['source'] = self.source
        if self.info:
            doc['info'] = _plain(self.info)
        return doc

    def to_json(self) -> str:
        """:meth:`to_mapping` as compact JSON (the ``plant_model`` parameter's value)."""
        return json.dumps(self.to_mapping(), sort_keys=True, separators=(',', ':'))

    @classmethod
    def from_mapping(cls, doc, *, dt: float, specimen: Specimen | None = None,
                     where: str = 'plant_model') -> 'PlantModel':
        """Build from a lab's description (see :func:`parse_plant`)."""
        return parse_plant(doc, dt=dt, specimen=specimen, where=where)


def _plain(value):
    """`value` with numpy scalars and arrays as plain Python numbers and lists."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def step_average_of(sampled, dt: float) -> np.ndarray:
    """The step-average response of a loop known at its samples (:func:`hold_factor`).

    Parameters
    ----------
    sampled : array_like, shape (n,)
        Impulse response at the samples.
    dt : float > 0
        Sample period [s].

    Returns
    -------
    ndarray, shape (n,)
        ``IFFT(FFT(sampled) (z - 1)/(j omega dt))`` on ``max(4096, 2 n)`` points, the first n.
    """
    y = np.asarray(sampled, dtype=float)
    nfft = max(4096, 2 * y.shape[0])
    freq = np.fft.rfftfreq(nfft, dt)
    return np.fft.irfft(np.fft.rfft(y, nfft) * hold_factor(freq, dt), nfft)[:y.shape[0]]


# -- a lab's description ------------------------------------------------------------------

def _number(value, where: str, *, positive: bool = False, nonneg: bool = False) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value)
    if ok and positive:
        ok = value > 0
    if ok and nonneg:
        ok = value >= 0
    if not ok:
        what = 'a number > 0' if positive else 'a number >= 0' if nonneg else 'a number'
        raise ParameterError(f'{where}={value!r}: expected {what}')
    return float(value)


def _vector(value, where: str) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or not value:
        raise ParameterError(f'{where}: expected a non-empty list of numbers')
    return np.array([_number(v, f'{where}[{i}]') for i, v in enumerate(value)])


def _matrix(value, where: str) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or not value:
        raise ParameterError(f'{where}: expected a list of rows')
    if not isinstance(value[0], (list, tuple)):               # a column given flat
        return _vector(value, where)[:, None]
    rows = [_vector(r, f'{where}[{i}]') for i, r in enumerate(value)]
    if len({r.shape[0] for r in rows}) != 1:
        raise ParameterError(f'{where}: expected rows of one length')
    return np.vstack(rows)


def _outputs(doc, where: str, length: int | None):
    """``{output: row}`` of a mapping by output name (or of a list with ``outputs``)."""
    if isinstance(doc, Mapping):
        out = {}
        for key, value in doc.items():
            if key not in OUTPUTS:
                raise ParameterError(f'{where}: unknown output {key!r}; expected some of '
                                     + ', '.join(OUTPUTS))
            out[key] = _vector(value, f'{where}.{key}')
        if 'force_N' not in out:
            raise ParameterError(f'{where}: expected the force_N output (valve command to '
                                 'measured force)')
        for key, row in out.items():
            if length is not None and row.shape[0] != length:
                raise ParameterError(f'{where}.{key}: expected {length} numbers (one per '
                                     f'state), got {row.shape[0]}')
        return out
    raise ParameterError(f'{where}: expected a mapping of outputs ({", ".join(OUTPUTS)}) to '
                         'their rows')


def _specimen_states(specimen: Specimen):
    """Continuous ``(a, b, c)`` of ``x = f / (m s^2 + c s + k)`` with outputs (x, v, a)."""
    m, c, k = specimen.mass_kg, specimen.damping_N_s_per_m, specimen.stiffness_N_per_m
    a = np.array([[0.0, 1.0], [-k / m, -c / m]])
    b = np.array([[0.0], [1.0 / m]])
    cc = np.array([[1.0, 0.0], [0.0, 1.0], [-k / m, -c / m]])
    d = np.array([[0.0], [0.0], [1.0 / m]])
    return a, b, cc, d


def _with_motion(a, b, rows: dict, specimen: Specimen | None, dt: float | None, where: str):
    """The full ``c`` (:data:`OUTPUTS`) from the given rows, the motion derived from the
    force through the specimen where a row is missing (continuous: exactly, in series;
    discrete: the specimen sampled with a first-order hold of the force,
    ``scipy.signal.cont2discrete`` method 'foh', Franklin, Powell and Workman 1998,
    Sec. 6.3.2)."""
    missing = [o for o in MOTION_OUTPUTS if o not in rows]
    n = a.shape[0]
    if not missing:
        return a, b, np.vstack([rows[o] for o in OUTPUTS])
    if specimen is None:
        raise ParameterError(f'{where}: outputs {", ".join(missing)} are missing and there is '
                             'no specimen to derive them from the force (give specimen: '
                             '{mass_kg, damping_N_s_per_m, stiffness_N_per_m}, or every output)')
    sa, sb, sc, sd = _specimen_states(specimen)
    if dt is not None:
        from scipy.signal import cont2discrete
        sa, sb, sc, sd, _ = cont2discrete((sa, sb, sc, sd), dt, method='foh')
    force = rows['force_N']
    big = np.zeros((n + 2, n + 2))
    big[:n, :n] = a
    big[n:, :n] = sb @ force[None]
    big[n:, n:] = sa
    bb = np.vstack([b, np.zeros((2, 1))])
    motion = np.hstack([sd @ force[None], sc])          # (x, v, a) = sc w + sd f
    full = {o: np.concatenate([rows[o], np.zeros(2)]) for o in rows}
    for i, o in enumerate(MOTION_OUTPUTS):
        if o in missing:
            full[o] = motion[i]
    return big, bb, np.vstack([full[o] for o in OUTPUTS])


def parse_plant(doc, *, dt: float, specimen: Specimen | None = None,
                where: str = 'plant_model') -> PlantModel:
    """A :class:`PlantModel` from a lab's description (YAML mapping or its JSON).

    Parameters
    ----------
    doc : mapping or str
        The description (a JSON string is read first)::

            form: state_space | transfer_function
            dt: 0.002          # the model's period [s]; absent or 0: continuous
            io_delay_s: 0.003  # pure delay of the command [s] (discrete: whole steps;
                               # at most MAX_IO_DELAY_STEPS steps of dt)
            # state_space: s' = a s + b u (or s[k+1] = ...), y = c s
            a: [[...], ...]
            b: [...]
            c: {force_N: [...], displacement_m: [...], ...}
            # transfer_function: polynomials in s or in z, descending powers
            num: {force_N: [...], ...}
            den: [...]
            specimen: {mass_kg: .., damping_N_s_per_m: .., stiffness_N_per_m: ..}
            uncertainty: {relative: 0.05, band_hz: [0.5, 40]}
            source: text

        The force output is required; the motion outputs may be left out when the specimen
        is given (they are then derived from the force, ``m x'' + c x' + k x = f``, paper
        Eq. 5.1: exactly from a continuous model; from a discrete one through the specimen
        sampled with a first-order hold of the force, within ``(omega dt)^2/12`` in
        displacement and velocity and ``(omega_n dt)^2/12`` in acceleration, omega_n the
        specimen's: give every output when you have them).
    dt : float > 0
        The run's control period [s]: a continuous model is sampled at it (zero-order hold,
        :func:`sample_continuous`); a discrete one must have it.
    specimen : Specimen, optional
        The specimen when the description has none.
    where : str
        The parameter or file, for the messages.

    Returns
    -------
    PlantModel

    Raises
    ------
    ParameterError
        Not a mapping, an unknown form or output, shapes that do not fit, a feedthrough (the
        sample of step k would depend on its own command), a discrete model of another period,
        a discrete delay that is not whole steps, a delay longer than
        :data:`MAX_IO_DELAY_STEPS` steps, a force that does not depend on the valve command
        (a zero force row or numerator), an unknown key (in the specimen and uncertainty too).
        The message names `where` and the field.
    """
    from seft_msgs_py.parameters import mapping_value
    doc = mapping_value(doc, where=where,
                        expected='a plant model mapping (form, dt, a/b/c or num/den, ...)')
    _known_fields(doc, ('form', 'dt', 'io_delay_s', 'a', 'b', 'c', 'd', 'num', 'den',
                        'specimen', 'uncertainty', 'source', 'info'), where)
    form = doc.get('form')
    if form not in _FORMS:
        raise ParameterError(f'{where}.form={form!r}: expected one of '
                             + ', '.join(repr(f) for f in _FORMS))
    run_dt = _number(dt, 'dt', positive=True)
    model_dt = doc.get('dt', 0.0) or 0.0
    model_dt = _number(model_dt, f'{where}.dt', nonneg=True)
    discrete = model_dt > 0
    if discrete and abs(model_dt - run_dt) > 1e-9 * run_dt:
        raise ParameterError(f'{where}.dt={model_dt:g}: a discrete model must have the '
                             f"run's period dt={run_dt:g} s (give it continuous, or identify "
                             'it at this period)')
    delay = _number(doc.get('io_delay_s', 0.0) or 0.0, f'{where}.io_delay_s', nonneg=True)
    if delay > MAX_IO_DELAY_STEPS * run_dt * (1 + 1e-9):
        raise ParameterError(f'{where}.io_delay_s={delay:g}: expected at most '
                             f"{MAX_IO_DELAY_STEPS} steps of the run's dt={run_dt:g} s "
                             f'({MAX_IO_DELAY_STEPS * run_dt:g} s; each step is a state of the '
                             'sampled model)')
    if 'specimen' in doc:
        specimen = Specimen.from_mapping(doc['specimen'], where=f'{where}.specimen')
    unc = (PlantUncertainty.from_mapping(doc['uncertainty'], where=f'{where}.uncertainty')
           if 'uncertainty' in doc else None)
    if form == 'state_space':
        for key in ('a', 'b', 'c'):
            if key not in doc:
                raise ParameterError(f'{where}: a state_space model needs a, b and c '
                                     f'({key} missing)')
        a = _matrix(doc['a'], f'{where}.a')
        n = a.shape[0]
        if a.shape != (n, n):
            raise ParameterError(f'{where}.a: expected a square matrix, got {a.shape}')
        b = _matrix(doc['b'], f'{where}.b').reshape(-1, 1)
        if b.shape[0] != n:
            raise ParameterError(f'{where}.b: expected {n} numbers (one input: the valve '
                                 f'command), got {b.size}')
        rows = _outputs(doc['c'], f'{where}.c', n)
        if not np.any(b):
            raise ParameterError(f'{where}.b: all zero: the valve command drives nothing; '
                                 'expected the input column of the valve command')
        if _zero_response(a, b, rows['force_N']):
            raise ParameterError(f'{where}.c.force_N: the force does not depend on the valve '
                                 'command (c.force_N (sI - a)^-1 b is zero); expected the '
                                 'force row of the model')
        if not _all_zero(doc.get('d', 0.0)):
            raise ParameterError(f'{where}.d: expected zero (no feedthrough: the sample of t_k '
                                 'cannot depend on the command of step k; put a delay in '
                                 'io_delay_s)')
    else:
        for key in ('num', 'den'):
            if key not in doc:
                raise ParameterError(f'{where}: a transfer_function model needs num and den '
                                     f'({key} missing)')
        den = _vector(doc['den'], f'{where}.den')
        if den[0] == 0:
            raise ParameterError(f'{where}.den: expected a non-zero leading coefficient')
        nums = _outputs(doc['num'], f'{where}.num', None)
        if not np.any(nums['force_N']):
            raise ParameterError(f'{where}.num.force_N: all zero: the force does not depend '
                                 'on the valve command; expected a non-zero numerator')
        for key, num in nums.items():
            num = np.trim_zeros(num, 'f')
            if num.size >= den.size:
                raise ParameterError(
                    f'{where}.num.{key}: expected a strictly proper transfer function (degree '
                    f"below the denominator's {den.size - 1}: the sample of t_k cannot depend "
                    'on the command of step k; put a delay in io_delay_s)')
        a, b, rows = _tf_to_states(den, nums)
    if discrete:
        steps = delay / run_dt
        if abs(steps - round(steps)) > 1e-6:
            raise ParameterError(f'{where}.io_delay_s={delay:g}: a discrete model takes whole '
                                 f'steps of dt={run_dt:g} s')
        a, b, c = _with_motion(a, b, rows, specimen, run_dt, where)
        a, b, c = _delay_states(a, b, c, int(round(steps)))
    else:
        a, b, c = _with_motion(a, b, rows, specimen, None, where)
        a, b, c = sample_continuous(a, b, c, run_dt, delay)
    info = doc.get('info') if isinstance(doc.get('info'), Mapping) else None
    return PlantModel(a, b, c, run_dt, specimen=specimen, uncertainty=unc,
                      source=str(doc.get('source', '') or f'{where} ({form}, '
                                 f'{"discrete" if discrete else "continuous"})'),
                      info=info)


def _known_fields(doc: Mapping, known, where: str) -> None:
    """Refuse a key of `doc` not in `known`, naming it and the expected ones."""
    unknown = sorted(str(k) for k in set(doc) - set(known))
    if unknown:
        raise ParameterError(f'{where}: unknown field(s) {", ".join(unknown)}; expected some '
                             f'of {", ".join(sorted(known))}')


def _zero_response(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> bool:
    """Whether ``c (sI - a)^-1 b`` (or in z) is zero: `c` orthogonal to each Krylov vector
    ``a^k b``, k < n, each normalized (relative 1e-12), so that no power overflows."""
    v = b[:, 0].astype(float)
    scale = float(np.linalg.norm(c))
    if scale == 0.0:
        return True
    for _ in range(a.shape[0]):
        norm = float(np.linalg.norm(v))
        if norm == 0.0:
            break
        v = v / norm
        if abs(float(c @ v)) > 1e-12 * scale:
            return False
        v = a @ v
    return True


def _all_zero(value) -> bool:
    """Whether a number, list or mapping of them holds only zeros (non-numbers: False)."""
    if isinstance(value, Mapping):
        return all(_all_zero(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return all(_all_zero(v) for v in value)
    return isinstance(value, (int, float)) and not isinstance(value, bool) and value == 0


def _tf_to_states(den: np.ndarray, nums: dict):
    """Controllable canonical form of ``num_i/den`` with one denominator (descending powers
    of s or z, strictly proper): ``(a, b, {output: row})``; the states are shared, each output
    has its own row."""
    n = den.size - 1
    scale = float(den[0])
    a = np.zeros((n, n))
    a[0] = -den[1:] / scale
    if n > 1:
        a[1:, :-1] = np.eye(n - 1)
    b = np.zeros((n, 1))
    b[0, 0] = 1.0
    rows = {}
    for key, num in nums.items():
        num = np.trim_zeros(np.asarray(num, dtype=float), 'f') / scale
        padded = np.concatenate([np.zeros(n + 1 - num.size), num])
        rows[key] = padded[1:]                  # strictly proper: padded[0] == 0
    return a, b, rows
