"""The reference-force builder of substructure EFT and its delay-compensation plug-in point.

Every test is a structure (:mod:`seft_ros.core.structure`); the reference study's test is its
one-DOF case. :class:`ReferenceForceBuilder` builds the reference forces of the rigs it
commands, one step at a time, from the record and the measured responses of every rig: for
each rig, :class:`RigReferenceForce` (paper Eq. 2.5 with that rig's delay compensator, a
:class:`Predictor`), with the interface force of the computational part added
(:mod:`seft_ros.core.substructure`: the computational DOFs integrated from the measured
motion, the interface force as the rig's compensator sees it). With one rig and nothing
computational but its rigid mass (the study), the interface force is zero and the builder
is :class:`RigReferenceForce` itself, bit for bit.
"""

from collections import deque
import math
from typing import Callable, Mapping, NamedTuple, Protocol, Sequence, runtime_checkable

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import Measurement
from seft_msgs_py.sampling import single_blas_thread
from seft_msgs_py.sensor_range import CHANNELS, SensorRanges
from seft_ros.core.predictors import (
    TANGENT_STIFFNESS_RATIOS,
    AdaptivePredictor,
    AtsPredictor,
    DelayImpulseModel,
    NoPredictor,
    PolynomialPredictor,
    foh_split,
    foh_split_average,
    foh_step_average,
    model_parameters,
    model_predictor,
    network_delay_steps,
)
from seft_ros.core.range_guard import RangeGuard, range_warning
from seft_ros.core.structure import TestSetup, test_setup
from seft_ros.core.substructure import (
    InterfacePredictor,
    SpecimenModel,
    computational_part,
    structure_matrices,
    tangent_matrices,
)
from seft_ros.core.tangent import YieldMechanisms

__all__ = ['Predictor', 'NoPredictor', 'PREDICTORS', 'make_predictor', 'ReferenceForceBuilder',
           'RigReferenceForce', 'ground_window', 'with_loop_latency', 'network_delay_steps',
           'specimen_model_of', 'Coupling', 'TANGENT_FLOOR',
           'below_tangent_floor']


@runtime_checkable
class Predictor(Protocol):
    """Delay compensator: estimate of the specimen acceleration fed back into the reference force.

    Called once per step k with the latest measurement, that of step k-1 (None before the
    first sample: the specimen is at rest), the desired forces already built
    (``F[0..k-1]``) and the ground-motion part ``G[k] = -(1 + alpha) m gbar[k]`` [N] of the
    new force (the compensator may solve the algebraic loop through it); returns
    ``a_hat[k]`` [m/s^2]. The builder forms ``F[k] = G[k] - alpha m a_hat[k]`` and sends
    ``command(F[k])`` (the identity, except for a force-loop inverse).

    Attributes
    ----------
    name : str
        Registry name (parameter ``predictor``).
    step_average : bool
        The ground term is the step average of the (linearly interpolated) record over the
        step in which the force acts (hold-consistent compensators), not the sample
        ``xg''[k]`` (paper Eq. 5.3).
    delay_s : float
        Loop delay the compensator assumes [s] (the shift of the ground-motion preview).
    interface : {'sampled', 'extrapolated', 'predicted'}, optional
        How the rig's interface force in a structure is formed for it
        (:mod:`seft_ros.core.substructure`); default 'predicted'.
    """

    name: str
    step_average: bool
    delay_s: float

    def predict(self, latest: Measurement | None, commanded_N: list[float],
                ground_force_N: float = 0.0) -> float:
        """Return the fed-back acceleration estimate [m/s^2]."""

    def command(self, force_N: float) -> float:
        """Return the command sent to the actuator for the desired force [N]."""


#: Delay compensators by name (parameter ``predictor``).
PREDICTORS: dict[str, Callable] = {
    'none': NoPredictor.from_parameters,
    'polynomial': PolynomialPredictor.from_parameters,
    'model': model_predictor,
    'adaptive': AdaptivePredictor.from_parameters,
    'ats': AtsPredictor.from_parameters,
}


def with_loop_latency(params) -> dict:
    """The parameters a predictor models, with the measured loop latency added.

    In real time with ``realtime_output: on_arrival`` a command acts when it arrives, so the
    loop's delay differs from the lockstep one by ``L - dt``, where ``L`` is the loop latency
    (sample to command at the rig) and ``dt`` the control period that lockstep assumes.
    With ``predictor_loop_latency_s = L > 0`` the predictor models the actuator delay
    ``tau + L - dt`` on the delay rig (``predictor_tau_s``, 0: ``tau_s``) and the I/O latency
    ``io_latency_s + L - dt`` on the servohydraulic rig, so that compensation covers the
    actuator and the communication together. ``L = 0`` (the default) changes nothing.

    With ``network_delay_s > 0`` (the builder on another host) the force servo controller
    applies each reference force ``N = round(network_delay_s / dt) dt`` later
    (:func:`network_delay_steps`): a pure delay in series with the actuator, outside the force
    loop. The predictor then predicts N beyond the force loop's inverted delay
    (:meth:`~seft_ros.core.predictors.ModelPredictor.from_parameters`); the force loop's own
    model is unchanged.

    Parameters
    ----------
    params : mapping
        The resolved parameters.

    Returns
    -------
    dict
        A copy with ``predictor_tau_s`` and ``io_latency_s`` adjusted (never below 0; the
        delay stays above 0).

    Raises
    ------
    ParameterError
        ``predictor_loop_latency_s > 0`` with ``realtime_output: latched`` (the default):
        there a command acts at the next tick whatever its latency, so the latency is no
        delay of the loop, and a predictor told it predicts too far (told the 3.6 ms loop
        latency of a builder on another host, ``model`` missed by about 4 % instead of
        0.4 %; the network's delay is ``network_delay_s``'s to cover).
    """
    out = dict(params)
    latency = float(params.get('predictor_loop_latency_s', 0.0) or 0.0)
    if latency > 0.0 and params.get('realtime_output', 'on_arrival') != 'on_arrival':
        raise ParameterError(
            f'parameter predictor_loop_latency_s={latency:g}: applies with realtime_output '
            "'on_arrival' only; with 'latched' output a command acts at the next tick "
            'whatever its latency, and a predictor told it would predict too far (set it to 0; '
            'a builder on another host: network_delay_s)')
    steps = network_delay_steps(params)
    network = steps * float(params['dt']) if steps else 0.0
    if latency <= 0.0 and network <= 0.0:
        return out
    extra = latency - float(params['dt']) if latency > 0.0 else 0.0
    tau = float(params.get('predictor_tau_s') or params.get('tau_s') or 0.0)
    out['predictor_tau_s'] = max(tau + extra + network, 1e-6)
    if 'io_latency_s' in params and latency > 0.0:
        out['io_latency_s'] = max(float(params['io_latency_s']) + extra, 0.0)
        if float(params.get('predictor_io_latency_s', 0.0) or 0.0) > 0.0:
            out['predictor_io_latency_s'] = max(
                float(params['predictor_io_latency_s']) + extra, 1e-9)
    return out


def make_predictor(params) -> Predictor:
    """Build the predictor named by ``params['predictor']`` (:func:`with_loop_latency`).

    Raises
    ------
    ParameterError
        If the name is not registered.
    """
    params = with_loop_latency(params)
    name = params['predictor']
    try:
        factory = PREDICTORS[name]
    except KeyError:
        choices = ', '.join(repr(n) for n in PREDICTORS)
        raise ParameterError(f'parameter predictor={name!r}: expected one of {choices}') from None
    return factory(params)


class RigReferenceForce:
    """Reference force of one rig from the ground motion and its fed-back acceleration.

    ``F[k] = -(1 + alpha) m iota g[k] + I[k] - alpha m a_hat[k]`` (paper Eq. 2.5 with the
    measured acceleration, Eq. 5.3; ``I`` the interface force of a structure's computational
    part, Eq. 2 of :mod:`seft_ros.core.structure`, 0 in the study's test), where
    ``a_hat[k]`` is the predictor's estimate (``none``: the measured acceleration of step
    k-1) and ``g[k]`` is the ground acceleration: the sample
    ``xg''[k]`` for ``none``, the step average of the linearly interpolated record over
    ``[t_k + s, t_k+1 + s]`` for the hold-consistent predictors, with ``s = 0`` or, with the
    ground-motion preview, ``s`` = the predictor's loop delay: the record is known before the
    test, so its part of the force is commanded ahead by the delay and the response no longer
    lags the reference. The command sent is ``predictor.command(F[k])``.

    Parameters
    ----------
    alpha : float >= 0
        Mass ratio (computational mass / specimen mass).
    mass_kg : float > 0
        Specimen mass m [kg].
    predictor : Predictor
    dt : float > 0, optional
        Control period [s]; needed by the preview.
    ground_preview : bool
        Shift the ground term ahead by the predictor's delay.
    influence : float
        The DOF's ground-motion influence ``iota`` [-] (1 in the study's test).

    Attributes
    ----------
    lookahead_steps : int
        How many samples after ``xg''[k]`` :meth:`step` reads (the window length - 1).

    Raises
    ------
    ParameterError
        If ``alpha < 0`` or ``mass_kg <= 0``.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eqs. 2.4-2.5 and 5.3.
    """

    def __init__(self, alpha: float, mass_kg: float, predictor: Predictor, *,
                 dt: float = 0.0, ground_preview: bool = False, influence: float = 1.0):
        if not alpha >= 0:
            raise ParameterError(f'parameter alpha={alpha!r}: expected float >= 0')
        if not mass_kg > 0:
            raise ParameterError(f'parameter mass_kg={mass_kg!r}: expected float > 0')
        self.alpha = float(alpha)
        self.mass_kg = float(mass_kg)
        self.predictor = predictor
        self.dt = float(dt)
        self.ground_preview = bool(ground_preview) and self.dt > 0
        self.commanded_N: list[float] = []
        self.last_ground_force_N = 0.0
        # G = ground_gain g (iota = 1: the product is exact, the study's number)
        self._ground_gain = -(1.0 + self.alpha) * self.mass_kg * float(influence)
        self._alpha_m = self.alpha * self.mass_kg
        # the preview's shift as foh_split splits it, for the compensator's delay [s] in use
        # (an adaptive compensator's moves): (delay, i, f)
        self._preview = (None, 0, 0.0)
        self.lookahead_steps = 0
        if getattr(predictor, 'step_average', False):
            self.lookahead_steps = 1
            if self.ground_preview:
                most = getattr(predictor, 'max_delay_s', predictor.delay_s)
                self.lookahead_steps = 1 + int(math.ceil(most / self.dt - 1e-9))

    @classmethod
    def from_parameters(cls, params, influence: float = 1.0) -> 'RigReferenceForce':
        """Build from ``alpha``, ``mass_kg``, ``dt``, ``ground_preview`` and ``predictor``."""
        return cls(float(params['alpha']), float(params['mass_kg']), make_predictor(params),
                   dt=float(params['dt']), ground_preview=bool(params['ground_preview']),
                   influence=influence)

    def ground(self, window) -> float:
        """The ground acceleration g[k] [m/s^2] of the new force from ``xg''[k..k+L]``."""
        if not self.predictor.step_average:
            return float(window[0])
        shift = self.predictor.delay_s / self.dt if self.ground_preview else 0.0
        return foh_step_average(window, shift)

    def step(self, ground, latest: Measurement | None,
             interface_N: float | None = None) -> float:
        """Return the command ``f_r[k]`` [N] from the ground motion and the measurement of k-1.

        Parameters
        ----------
        ground : float or sequence of float, shape (>= lookahead_steps + 1,)
            ``xg''[k]`` [m/s^2], or the window ``xg''[k], ..., xg''[k + lookahead_steps]``
            (zeros after the end of the record); a float is enough when
            ``lookahead_steps == 0``.
        latest : Measurement or None
            The measurement of step k-1 (None for k = 0).
        interface_N : float, optional
            The interface force ``I[k]`` [N] as the compensator sees it (a structure's rig
            coupled to its computational part); None: none (the study's test).
        """
        window = (ground,) if isinstance(ground, (int, float)) else ground
        if len(window) <= self.lookahead_steps:
            raise ParameterError(f'ground window of {len(window)} samples: expected '
                                 f'{self.lookahead_steps + 1} (xg[k..k+{self.lookahead_steps}])')
        return self.step_window(window, latest, interface_N)

    def step_window(self, window, latest: Measurement | None,
                    interface_N: float | None = None) -> float:
        """:meth:`step` from a window already known to be long enough (the builder's)."""
        predictor = self.predictor
        if not predictor.step_average:             # self.ground(window), written out
            g = float(window[0])
        elif self.ground_preview:                  # foh_step_average, its split kept
            delay, i, f = self._preview
            if delay != predictor.delay_s:
                delay = predictor.delay_s
                i, f = foh_split(delay / self.dt)
                self._preview = (delay, i, f)
            g = 0.5 * (window[i] + window[i + 1]) if f < 1e-12 else foh_split_average(window, i, f)
        else:
            g = 0.5 * (window[0] + window[1])      # foh_step_average(window, 0.0)
        ground_force = self.last_ground_force_N = self._ground_gain * g
        if interface_N is not None:
            ground_force += interface_N
        a_hat = predictor.predict(latest, self.commanded_N, ground_force)
        force = ground_force - self._alpha_m * a_hat
        self.commanded_N.append(force)
        return predictor.command(force)


#: The compensators' estimate of a yielding member's tangent stiffness (its model's).
TANGENT_ESTIMATE = 'tangent_stiffness_N_per_m'


def yields(predictor) -> bool:
    """Whether a compensator models a member that yields (it estimates its tangent
    stiffness: ``predictor_restoring_force`` 'measured' or 'hysteretic')."""
    return TANGENT_ESTIMATE in getattr(predictor, 'ESTIMATES', ())


def specimen_model_of(predictor, params) -> SpecimenModel:
    """The specimen model a rig's compensator works with: its identified one for
    ``adaptive``; for a member that yields, the configured ``m, c`` with its current tangent
    stiffness (on a table 5 % apart, ``TANGENT_STIFFNESS_RATIOS``); the configured one
    (``predictor_*``, 0: the specimen's) for a compensator without a model (``none``,
    ``polynomial``)."""
    if yields(predictor):
        mp = model_parameters(params)
        k = mp['stiffness_N_per_m']
        k_t = float(predictor.estimates()[TANGENT_ESTIMATE])
        ratios = TANGENT_STIFFNESS_RATIOS
        i = int(np.argmin(np.abs(np.log(ratios) - math.log(max(k_t / k, ratios[0])))))
        return SpecimenModel(mp['mass_kg'], mp['damping_N_s_per_m'], k * float(ratios[i]))
    model = getattr(predictor, 'model', None)
    if isinstance(model, DelayImpulseModel):
        return SpecimenModel(model.mass_kg, model.damping_N_s_per_m, model.stiffness_N_per_m)
    mp = model_parameters(params)
    return SpecimenModel(mp['mass_kg'], mp['damping_N_s_per_m'], mp['stiffness_N_per_m'])


class Coupling(NamedTuple):
    """How a builder's local rigs see the interface force (:meth:`ReferenceForceBuilder.coupling`).

    Attributes
    ----------
    modes : list of str or None
        Per local rig: None (not coupled), 'sampled', 'extrapolated' or 'predicted'.
    sampled : ndarray, shape (n_l, 2 n), or None
        ``I = sampled [x, v]`` at a sample (every DOF's x, then v) [N].
    predicted : ndarray, shape (n_targets, width), or None
        The ``matrix`` of the :class:`~seft_ros.core.substructure.InterfacePredictor` of the
        targets.
    targets : list of int
        The local rigs (indices) whose interface is predicted, in the rows' order.
    history_steps, ground_steps : int
        ``nh`` and ``ng`` of the prediction's ``q``.
    weights : dict of int to list of float
        Per extrapolated local rig: the weights on ``I[k], I[k-1], ...``.
    """

    modes: list
    sampled: 'np.ndarray | None'
    predicted: 'np.ndarray | None'
    targets: list
    history_steps: int
    ground_steps: int
    weights: dict


#: The interface predictions a builder keeps, by their models (a yielding member's tangent
#: stiffness moves between a few values of its table).
INTERFACE_CACHE = 64

#: Builders of one test exchange their rigs' specimen models every this many steps (a lab's
#: replica of the computational part then models another lab's pier as identified there)...
EXCHANGE_EVERY_STEPS = 50
#: ... and take those sent after step j in at step j + this (lockstep waits for them: the
#: same steps in ``seft simulate`` and the graph, bit for bit).
EXCHANGE_LAG_STEPS = 25

#: A rig's specimen model or loop delay that moved by more than this (relative; the delay:
#: ``dt / 64``) rebuilds the interface prediction (an ``adaptive`` compensator's estimates).
#: A coupled test is sensitive to it: with 1 % (before session 33) the prediction kept the
#: model an ``adaptive`` rig had after its first half second, 0.1-0.2 % off the specimen it
#: then identified exactly, and lab plants seft did not write under a computational story
#: erred 1.5-2.5 % NRMS x where ``model`` gives 0.02-0.22 %; with 0.1 % the same runs give
#: ``model``'s figures, for 2-3 times the rebuilds (each about 0.4-0.8 ms, most within the
#: identification's first second).
MODEL_TOLERANCE = 0.001

#: A computational part's tangent stiffness (a model that yields) is predicted with on a grid
#: of this part of the largest entry of its initial stiffness (the deviation from it is
#: rounded; a tangent within half a step of the initial one is the initial one, exactly): the
#: predictions built for a member's few tangents are kept (:data:`INTERFACE_CACHE`).
TANGENT_STEP = 0.005
#: The floor of the tangent the compensators predict with [-]: where the computational
#: DOFs' block of the (quantized) tangent is below this part of the initial stiffness's in
#: some direction (a member that yields perfectly plastic: `Steel01` with b 0, `ElasticPP`;
#: its tangent zero, or rounded to zero on the ``TANGENT_STEP`` grid), the prediction
#: takes the tangent plus this part of the initial stiffness: the plateau's force held by a
#: spring of this part of the member's elastic stiffness anchored far off (the prediction's
#: static shift needs the block's inverse), whose force over the prediction's horizon
#: changes by this part of the elastic member's. A post-yield ratio of 0.001 or more is
#: taken as it is (its grid value at 0.005 of the largest stiffness permitting).
TANGENT_FLOOR = 1e-3


class ReferenceForceBuilder:
    """The reference forces of the rigs of a test, one step at a time.

    Every test is a structure (:mod:`seft_ros.core.structure`); the reference study's test is
    its one-DOF case. Measurements are handed in as they come (:meth:`observe`, any rig, any
    order); :meth:`step` then returns the commands ``f_r[k]`` of the **local** rigs (those
    this builder commands: every rig on one host, its own rig for a lab's replica). Each
    local rig ``p`` gets :class:`RigReferenceForce` with its own compensator (``predictor``
    and its parameters from the rig's section) and, where the computational part is
    attached to its DOF, the interface force ``I_p`` of Eq. 2
    (:mod:`seft_ros.core.substructure`: ``'sampled'`` at ``k-1`` for ``none``,
    ``'extrapolated'`` for ``polynomial``, ``'predicted'`` over the interval where the new
    force acts for the model-based compensators, from the coupled model with each local
    rig's current specimen model). The computational DOFs are integrated from every rig's
    measured motion (:class:`~seft_ros.core.substructure.StructureState`); in the study's
    test there is nothing to integrate and the builder is the rig's
    :class:`RigReferenceForce`, bit for bit.

    Parameters
    ----------
    setup : TestSetup
    dt : float > 0
        Control period [s].
    laws : sequence of RigReferenceForce
        One per local rig, in structure order.
    rig_params : sequence of mapping
        Each local rig's parameters (its compensator's), in the same order.
    local : sequence of str, optional
        The rigs this builder commands (default: all, in structure order).
    interface_corrections : mapping of str to (float, float, float, float), optional
        Per rig, the coupled loop's calibration of the interface force its compensator sees
        (:func:`~seft_ros.core.law_calibration.structure_calibration`; the `corrections` of
        :class:`~seft_ros.core.substructure.InterfacePredictor`); default none.

    Attributes
    ----------
    rig_names : tuple of str
        Every rig of the structure (the order of :meth:`observe`'s index).
    local_rigs : tuple of str
        The rigs :meth:`step` returns commands for, in structure order.
    laws : list of RigReferenceForce
        Their reference forces and compensators.
    next_step : int
        The step ``k`` of the next :meth:`step`.
    lookahead_steps : int
        How many samples after ``xg''[k]`` :meth:`step` reads.
    last_ground_forces_N : list of float
        The effective force ``-(m_p + mu_p) iota_p xg''`` of each local rig's latest command
        [N] (the instability monitor's scale).
    computational_state : tuple of float
        ``x_Q, v_Q, a_Q`` of sample ``k - 1 - state_lag_steps`` as the latest :meth:`step`
        recorded them [m, m/s, m/s^2], in the order of ``state_names``.
    state_lag_steps : int
        0, or 1 for a part that steps its model after the command (:meth:`advance`).
    state_names : tuple of str
        ``'<dof>/displacement_m'``, ``'<dof>/velocity_m_s'``, ``'<dof>/acceleration_m_s2'``
        per computational DOF.
    window_steps : int
        The window of the latest :meth:`step` (0: every measurement of ``k-1`` was in).
    interface_N : list of float or None
        The interface force of each local rig in the latest step [N] (None: not coupled).

    Raises
    ------
    ParameterError
        An unknown local rig, or laws and parameters that do not match the local rigs.
    """

    def __init__(self, setup: TestSetup, dt: float, laws: Sequence[RigReferenceForce],
                 rig_params: Sequence[Mapping], local: Sequence[str] | None = None,
                 interface_corrections: Mapping | None = None):
        self.setup = setup
        #: the coupled loop's calibration per rig (the interface force as its compensator
        #: sees it), ``{rig: (s_c, s_k, c_r, k_r)}``
        self.interface_corrections = dict(interface_corrections or {})
        sub = setup.substructures
        s = sub.structure
        self.dt = float(dt)
        self.rig_names = setup.rig_names
        names = self.rig_names
        local = names if local is None else tuple(local)
        unknown_rigs = [r for r in local if r not in names]
        if unknown_rigs or not local:
            raise ParameterError(f'local rigs {list(local)!r}: expected some of '
                                 f'{", ".join(repr(r) for r in names)}')
        self.local_rigs = tuple(r for r in names if r in local)
        self.laws = list(laws)
        self._rig_params = [dict(p) for p in rig_params]
        #: each local rig's parameters (its compensator's), in the order of `local_rigs`
        self.rig_params = self._rig_params
        if len(self.laws) != len(self.local_rigs) or len(self._rig_params) != len(self.laws):
            raise ParameterError(f'reference-force builder: {len(self.laws)} laws for the '
                                 f'local rigs {", ".join(self.local_rigs)}')
        pi = list(s.physical_index)
        self._local_pos = [names.index(r) for r in self.local_rigs]
        self._local_of = {j: r for r, j in enumerate(self._local_pos)}   # position -> local
        self._local_dof = [pi[j] for j in self._local_pos]
        self.n_l = len(self.laws)
        self.predictor = self.laws[0].predictor if self.n_l == 1 else None
        self.next_step = 0
        self.window_steps = 0
        self.last_ground_forces_N = [0.0] * self.n_l
        # the interface force of each local rig: coupled when the computational part holds
        # springs or dashpots on its DOF (Eq. 2)
        kc, cc = sub.stiffness_c_N_per_m, sub.damping_c_N_s_per_m
        self._coupled = [bool(kc[i].any() or cc[i].any()) for i in self._local_dof]
        self._modes = [getattr(law.predictor, 'interface', 'predicted') if c else None
                       for law, c in zip(self.laws, self._coupled)]
        self.interface_N = [0.0 if c else None for c in self._coupled]
        self._tracking = bool(s.computational_index) or any(self._coupled)
        self.state = computational_part(sub, self.dt) if self._tracking else None
        self.state_names = self.state.state_names if self.state is not None else ()
        self.computational_state = tuple([0.0] * len(self.state_names))
        self.state_lag_steps = int(getattr(self.state, 'recorded_lag_steps', 0))
        self._latest: list[dict] = [{} for _ in self.laws]
        #: the rigs other builders command (their models come by :meth:`receive_models`)
        self.remote_rigs = tuple(r for r in names if r not in self.local_rigs)
        # a step does more than its laws (other builders' models, a computational part)
        self._couples = bool(self.remote_rigs) or self._tracking
        # the law of a builder of one rig whose step is its law's alone (a one-DOF test: no
        # structure, no other builder); None otherwise
        self._only_law = self.laws[0] if self.n_l == 1 and not self._couples else None
        self._inbox: dict[int, dict] = {}
        self._remote_models: dict[int, SpecimenModel] = {}    # rig position -> its model
        #: ``(step, {rig: SpecimenModel})`` of the local rigs, set every
        #: EXCHANGE_EVERY_STEPS steps for the other builders (None before)
        self.outbox = None
        self._qi = list(s.computational_index)
        look = max(law.lookahead_steps for law in self.laws)
        self._history = {}
        self._interface = None
        self._targets = [r for r, m in enumerate(self._modes) if m == 'predicted']
        if any(self._coupled):
            for r, mode in enumerate(self._modes):
                if mode == 'extrapolated':
                    weights = [float(w) for w in self.laws[r].predictor.weights]
                    self._history[r] = (weights, deque([0.0] * len(weights),
                                                       maxlen=len(weights)))
        self._yields = [yields(law.predictor) for law in self.laws]
        # each local rig's readings against its sensors' ranges (flagged, counted, the
        # acceleration estimated while the accelerometer is at its range)
        self.range_guards = [self._range_guard(law, p, y) for law, p, y in
                             zip(self.laws, self._rig_params, self._yields)]
        self._interface_cache = {}
        self._tangent = None                 # the quantized K_c,t in use (None: K_c)
        self._tangent_key = None
        self._mechanisms = None              # a yielding part's mechanisms (core.tangent)
        if self._targets:
            self._interface_key = None
            self._build_interface()
            taus = [float(getattr(law.predictor, 'max_delay_s', law.predictor.delay_s))
                    for law in self.laws]
            look = max(look, int(math.floor(2.0 + max(taus) / self.dt - 1e-9)))
        self.lookahead_steps = look

    # -- construction -----------------------------------------------------------------------

    @classmethod
    def from_parameters(cls, params, local: Sequence[str] | None = None,
                        interface_corrections: Mapping | str = 'auto'
                        ) -> 'ReferenceForceBuilder':
        """Build from a run's parameters (the structure, or the study's ``alpha``; each rig's
        parameters with its ``predictor``).

        `interface_corrections`: ``'auto'`` (the default) calibrates the coupled loop where
        a rig asks for it (:func:`~seft_ros.core.law_calibration.structure_calibration`:
        ``predictor_calibration: poles`` on a rig of a structure); a mapping gives them
        (the loop models of the calibration itself).

        Raises
        ------
        ParameterError
            As :func:`~seft_ros.core.structure.test_setup` and :func:`make_predictor`, and
            a calibration of the coupled loop that fails (the message says why).
        """
        setup = test_setup(params)
        sub = setup.substructures
        s = sub.structure
        names = setup.rig_names
        chosen = names if local is None else [r for r in names if r in local]
        laws, rig_params = [], []
        with single_blas_thread():
            for r in chosen:
                j = names.index(r)
                p = setup.rig_params[r]
                if not setup.is_study:
                    p = dict(p, alpha=float(sub.alpha[j]))
                try:
                    laws.append(RigReferenceForce.from_parameters(
                        p, influence=float(s.influence[s.physical_index[j]])))
                except ParameterError as exc:
                    if setup.is_study:
                        raise
                    raise ParameterError(f'rigs.{r}: {exc}') from None
                rig_params.append(p)
        if isinstance(interface_corrections, str):
            from seft_ros.core.law_calibration import structure_calibration
            interface_corrections = structure_calibration(params)
        return cls(setup, float(params['dt']), laws, rig_params, local=local,
                   interface_corrections=interface_corrections)

    def _range_guard(self, law, params, tangent: bool) -> 'RangeGuard | None':
        """A local rig's :class:`~seft_ros.core.range_guard.RangeGuard` (None: its sensors
        have no range)."""
        ranges = SensorRanges.from_parameters(params)
        if not ranges.limited:
            return None
        return RangeGuard(ranges, self.dt, law.predictor,
                          lambda: specimen_model_of(law.predictor, params),
                          tangent_only=tangent)

    def count_at_range(self, rig: int, measurement: Measurement) -> None:
        """Count a sample at a sensor's range that no force is built from (the run's last,
        or one the run was stopped at) as :meth:`observe` would, for a rig this builder
        commands (index in ``rig_names``; another rig's is ignored)."""
        if rig in self._local_pos:
            guard = self.range_guards[self._local_pos.index(rig)]
            if guard is not None:
                guard.take(measurement)

    def range_warnings(self) -> list[str]:
        """One line per local rig and channel that read its sensor's range for the first
        time since the last call (:func:`~seft_ros.core.range_guard.range_warning`)."""
        out = []
        for rig, guard in zip(self.local_rigs, self.range_guards):
            if guard is not None and guard.news:
                out.extend(range_warning(rig, c, guard.ranges.range_of(c), step * self.dt)
                           for c, step in guard.news)
                guard.news.clear()
        return out

    def part_findings(self) -> dict:
        """What the computational part found before or during the test (its optional
        ``findings()``, JSON-able: an OpenSees part's pushover), {} for a part without it or
        a builder without a computational part."""
        findings = getattr(self.state, 'findings', None)
        return dict(findings()) if findings is not None else {}

    def range_counts(self) -> dict:
        """Each local rig's samples at a sensor's range (``RangeCount.as_dict``) with its
        ranges (``'ranges'``: channel -> range in SI units, None unlimited), by rig name."""
        out = {}
        for rig, guard in zip(self.local_rigs, self.range_guards):
            if guard is not None:
                ranges = {c: (v if math.isfinite(v) else None)
                          for c, v in zip(CHANNELS, guard.ranges.ranges())}
                out[rig] = dict(guard.count.as_dict(), ranges=ranges)
        return out

    def _build_interface(self) -> None:
        """(Re)build the interface prediction from the local rigs' current specimen models
        and delays, when they moved (:data:`MODEL_TOLERANCE`), and the computational part's
        tangent stiffness in use (``_tangent_key``)."""
        models = [specimen_model_of(law.predictor, p)
                  for law, p in zip(self.laws, self._rig_params)]
        taus = [float(law.predictor.delay_s) for law in self.laws]
        key = self._interface_key
        if key is not None:
            old_models, old_taus, old_tangent = key
            if not any(m.moved(o, MODEL_TOLERANCE) for m, o in zip(models, old_models)) and all(
                    abs(t - o) <= self.dt / 64 for t, o in zip(taus, old_taus)) \
                    and old_tangent == self._tangent_key:
                return
        exact = (tuple((m.mass_kg, m.damping_N_s_per_m, m.stiffness_N_per_m) for m in models),
                 tuple(round(t / self.dt * 64) for t in taus), self._tangent_key)
        ip = self._interface_cache.get(exact)
        if ip is None:
            sub, matrices = self.setup.substructures, self.state.matrices
            if self._tangent is not None:
                matrices = tangent_matrices(sub, matrices, self._tangent)
            with single_blas_thread():
                corrections = None
                if self.interface_corrections:
                    corrections = [self.interface_corrections.get(self.local_rigs[t])
                                   for t in self._targets]
                ip = InterfacePredictor(
                    sub, self._local_pos, models, taus, self._targets, self.dt, matrices,
                    offsets=self._yields, stiffness_c_N_per_m=self._tangent,
                    corrections=corrections)
            if len(self._interface_cache) >= INTERFACE_CACHE:
                self._interface_cache.pop(next(iter(self._interface_cache)))
            self._interface_cache[exact] = ip
        self._interface = ip
        self._interface_models = models
        self._interface_key = (models, taus, self._tangent_key)

    def _use_tangent(self, stiffness_c_N_per_m) -> None:
        """Predict with the computational part's tangent `stiffness_c_N_per_m` (None: its
        linearization), rounded to the grid of :data:`TANGENT_STEP`."""
        if stiffness_c_N_per_m is None:
            self._tangent = self._tangent_key = None
            return
        k0 = self.setup.substructures.stiffness_c_N_per_m
        step = TANGENT_STEP * float(np.max(np.abs(k0)))
        grid = np.round((np.asarray(stiffness_c_N_per_m, dtype=float) - k0) / step)
        if not grid.any():
            self._tangent = self._tangent_key = None
            return
        key = grid.astype(np.int64).tobytes()
        if key != self._tangent_key:
            self._tangent_key = key
            self._tangent = _floored_tangent(k0 + grid * step, k0, self._qi)

    def set_specimen_model(self, rig: str, model: SpecimenModel) -> None:
        """Model rig `rig` (commanded elsewhere) with an identified specimen from now on: its
        DOF, when its measurement is late, and in the interface prediction, moves with
        `model` (another lab's estimate, exchanged over the network).

        Raises
        ------
        ParameterError
            No such rig, or a rig this builder commands (its compensator identifies it).
        """
        if rig not in self.rig_names or rig in self.local_rigs:
            raise ParameterError(f'rig {rig!r}: not a rig commanded elsewhere (rigs '
                                 f'{", ".join(repr(r) for r in self.rig_names)})')
        if self.state is None:
            return
        models = dict(self._remote_models)
        models[self.rig_names.index(rig)] = model
        self._remote_models = models
        self.state.set_matrices(structure_matrices(self.setup.substructures, models))
        if self._targets:
            self._interface_key = None
            self._interface_cache.clear()
            self._build_interface()

    def coupling(self) -> 'Coupling':
        """The linear maps from the structure's state to the local rigs' interface forces
        (the stability analysis closes the loop with them)."""
        sampled = None
        if any(self._coupled):
            n = self.setup.structure.n
            sub = self.setup.substructures
            sampled = np.array([np.concatenate([-sub.stiffness_c_N_per_m[i],
                                                -sub.damping_c_N_s_per_m[i]])
                                for i in self._local_dof]).reshape(self.n_l, 2 * n)
        ip = self._interface
        return Coupling(list(self._modes), sampled,
                        None if ip is None else ip.matrix, list(self._targets),
                        0 if ip is None else ip.history_steps,
                        0 if ip is None else ip.ground_steps,
                        {r: list(w) for r, (w, _) in self._history.items()})

    # -- stepping ---------------------------------------------------------------------------

    def observe(self, rig: int, measurement: Measurement) -> None:
        """Hand in one rig's measurement (any rig, any order; a repeat replaces it).

        Parameters
        ----------
        rig : int
            Index of the rig in ``rig_names``.
        measurement : Measurement
            Its sample (``measurement.step``).
        """
        r = self._local_of.get(rig)
        if r is not None:
            guard = self.range_guards[r]
            if guard is not None:
                measurement = guard.take(measurement)
        if self.state is not None:
            self.state.observe(rig, measurement)
        if r is not None:
            self._latest[r][measurement.step] = measurement

    def reference_late(self, step: int, late_s: float) -> None:
        """Real time: the reference forces of sample `step` went out `late_s` [s] after its
        sample time (the builder node, for every late one); each local rig's compensator
        that identifies from the forces it sent is told
        (``AdaptivePredictor.reference_late``)."""
        for law in self.laws:
            fn = getattr(law.predictor, 'reference_late', None)
            if fn is not None:
                fn(step, late_s)

    def estimates(self) -> list:
        """Each local rig's compensator's online estimates (a dict, keys its
        ``ESTIMATES``), or None for a compensator without estimates."""
        out = []
        for law in self.laws:
            fn = getattr(law.predictor, 'estimates', None)
            out.append(fn() if fn is not None else None)
        return out

    def observe_and_step(self, measurement: Measurement, window) -> float:
        """:meth:`observe` of the one local rig's measurement of sample ``k - 1`` (``k`` =
        ``next_step``), then :meth:`step`: its command ``f_r[k]`` [N] (a float). The
        same operations and results; a builder of one rig whose step is its law's alone
        (the study's test, a one-DOF test) takes the measurement straight to its law.

        Parameters
        ----------
        measurement : Measurement
            The local rig's sample ``k - 1``.
        window : sequence of float, length lookahead_steps + 1
            ``xg''[k .. k + lookahead_steps]`` [m/s^2].

        Raises
        ------
        ParameterError
            A builder of more than one local rig; as :meth:`step`.
        """
        law = self._only_law
        k = self.next_step
        if (law is None or measurement.step != k - 1 or self._latest[0]
                or len(window) <= self.lookahead_steps):
            if self.n_l != 1:
                raise ParameterError(f'reference-force builder of {self.n_l} local rigs: '
                                     'observe_and_step takes one')
            self.observe(self._local_pos[0], measurement)
            return self.step(window)[0]
        guard = self.range_guards[0]
        if guard is not None:
            measurement = guard.take(measurement)
        force = law.step_window(window, measurement)
        self.last_ground_forces_N[0] = law.last_ground_force_N
        self.next_step = k + 1
        return force

    def step(self, window) -> list[float]:
        """The commands ``f_r[k]`` of the local rigs [N], from the record and what has been
        observed (``k`` = ``next_step``).

        Parameters
        ----------
        window : sequence of float, length lookahead_steps + 1
            ``xg''[k .. k + lookahead_steps]`` [m/s^2] (zeros after the record).

        Returns
        -------
        list of float, length n_l
            The command of each local rig: the desired force (through its force-loop
            inverse, if any) [N].

        Raises
        ------
        ParameterError
            A short window, or a local rig's measurement of ``k-1`` not observed.
        """
        if len(window) <= self.lookahead_steps:
            raise ParameterError(f'ground window of {len(window)} samples: expected '
                                 f'{self.lookahead_steps + 1} (xg[k..k+{self.lookahead_steps}])')
        k = self.next_step
        law = self._only_law
        if law is not None:                 # the loop below for one rig, written out
            m = None
            if k > 0:
                seen = self._latest[0]
                m = seen.pop(k - 1, None)
                if m is None:
                    raise ParameterError(f'rig {self.local_rigs[0] or "rig"}: no measurement '
                                         f'of sample {k - 1} observed')
                if len(seen) > 4:
                    _forget_before(seen, k - 1)
            force = law.step_window(window, m)
            self.last_ground_forces_N[0] = law.last_ground_force_N
            self.next_step = k + 1
            return [force]
        if k > 0:
            latest = []
            for seen in self._latest:
                m = seen.pop(k - 1, None)
                if m is None:
                    raise ParameterError(f'rig {self.local_rigs[len(latest)] or "rig"}: no '
                                         f'measurement of sample {k - 1} observed')
                latest.append(m)
                if len(seen) > 4:                  # forget what came too late to be used
                    _forget_before(seen, k - 1)
        else:
            latest = [None] * self.n_l
        if self._couples:
            self._before_laws(k, window, latest)
        out = [0.0] * self.n_l
        interface, ground = self.interface_N, self.last_ground_forces_N
        for r, law in enumerate(self.laws):
            out[r] = law.step_window(window, latest[r], interface[r])
            ground[r] = law.last_ground_force_N
        if self.remote_rigs and k % EXCHANGE_EVERY_STEPS == 0:
            self.outbox = (k, self.local_models())
        self.next_step = k + 1
        return out

    def _before_laws(self, k: int, window, latest) -> None:
        """What a structure's step does before its laws: the other builders' models due at
        step `k` taken in, the computational state of ``k-1`` and the interface forces."""
        if self.remote_rigs:
            due = self.models_due(k)
            if due is not None:     # (in real time, one that came late: at the next due step)
                for stamp in sorted(j for j in self._inbox if j <= due):
                    for rig, model in self._inbox.pop(stamp).items():
                        self._receive(rig, model)
        if self._tracking:
            self._couple(k, window, latest)

    # -- the exchange of identified models between builders --------------------------------

    def local_models(self) -> dict:
        """Each local rig's specimen model as its compensator has it now (``adaptive``: its
        identified one), by rig name."""
        return {r: specimen_model_of(law.predictor, p)
                for r, law, p in zip(self.local_rigs, self.laws, self._rig_params)}

    def models_due(self, k: int) -> int | None:
        """The step whose models of the other builders' rigs step `k` takes in (None: none
        due; ``EXCHANGE_EVERY_STEPS``, ``EXCHANGE_LAG_STEPS``)."""
        stamp = k - EXCHANGE_LAG_STEPS
        if not self.remote_rigs or stamp < 0 or stamp % EXCHANGE_EVERY_STEPS:
            return None
        return stamp

    def advance(self) -> None:
        """Real time, once the step's commands are out: the work of the computational part
        that the next step needs but this step's commands did not (an OpenSees model with
        ``step: deferred`` stepped to the sample they were built from). The next step
        does it otherwise: the same results either way.

        Also rebuilds the interface prediction for the compensators' models as this step's
        laws left them (``adaptive``: its estimates moved by more than
        ``MODEL_TOLERANCE``), which the next step would otherwise rebuild before its
        commands: that step then finds it built for the same models (the same prediction
        either way; a tangent that moved meanwhile is rebuilt there)."""
        advance = getattr(self.state, 'advance', None)
        if advance is not None:
            advance()
        if self._interface is not None:
            self._build_interface()

    def refits(self) -> bool:
        """Whether a compensator of this builder refits during the run (the node then gives
        it a :class:`~seft_ros.core.predictors.BackgroundFits` in real time)."""
        return any(getattr(law.predictor, 'refits', lambda: False)() for law in self.laws)

    def run_fits_in_background(self, fits) -> None:
        """Real time: every compensator that refits (``run_fits_in_background``) does so on
        `fits` (:class:`~seft_ros.core.predictors.BackgroundFits`) instead of in the step."""
        for law in self.laws:
            attach = getattr(law.predictor, 'run_fits_in_background', None)
            if attach is not None:
                attach(fits)

    def receive_models(self, step: int, rig: str, model: SpecimenModel) -> None:
        """Hand in another builder's model of its rig `rig`, sent after its step `step`
        (applied at step ``step + EXCHANGE_LAG_STEPS``; a stamp off the exchange's grid or of
        a local rig is ignored)."""
        if rig in self.remote_rigs and step % EXCHANGE_EVERY_STEPS == 0:
            self._inbox.setdefault(step, {})[rig] = model

    def has_models(self, step: int) -> bool:
        """Whether every other builder's models of `step` are in (lockstep waits for them)."""
        return set(self._inbox.get(step, {})) >= set(self.remote_rigs)

    def _receive(self, rig: str, model: SpecimenModel) -> None:
        """Take another builder's model of `rig` when it moved (:data:`MODEL_TOLERANCE`)."""
        j = self.rig_names.index(rig)
        current = self._remote_models.get(j)
        if current is None:
            sub = self.setup.substructures
            current = SpecimenModel(float(sub.specimen_mass_kg[j]),
                                    float(sub.specimen_damping_N_s_per_m[j]),
                                    float(sub.specimen_stiffness_N_per_m[j]))
        if model.moved(current, MODEL_TOLERANCE):
            self.set_specimen_model(rig, model)

    def _prediction_input(self, k: int, window, latest, x, v) -> tuple[list, tuple | None]:
        """``q`` of the interface prediction (built for the tangent in use) and the residual
        to add to its forces (a model that is not its linearization), at step `k`."""
        self._build_interface()
        ip = self._interface
        nh = ip.history_steps
        q = x + v
        adjust = getattr(self.state, 'prediction_state', None)
        residual = None
        if adjust is not None:       # a model that is not its linearization (OpenSees)
            shifted, residual = adjust(x, v, [self._local_dof[r] for r in self._targets],
                                       self._tangent)
            q = list(shifted) + list(v)
        for law in self.laws:
            past = law.commanded_N[-nh:]
            q.extend([0.0] * (nh - len(past)) + past)
        q.append(0.0 if k == 0 else self.state.ground.get(k - 1, 0.0))  # g[k-1]
        q.extend(window[:ip.ground_steps - 1])
        for r in ip.offset_rigs:          # a yielding member: measured less modelled
            m, mod = latest[r], self._interface_models[r]
            q.append(0.0 if m is None else (
                m.force_N - mod.mass_kg * m.acceleration_m_s2
                - mod.damping_N_s_per_m * m.velocity_m_s
                - mod.stiffness_N_per_m * m.displacement_m))
        return q, residual

    def _couple(self, k: int, window, latest) -> None:
        """The computational state of sample ``k-1`` and the local rigs' interface forces
        (`latest`: each local rig's measurement of ``k-1``, None at the start)."""
        state = self.state
        for j, g in enumerate(window[:self.lookahead_steps + 1]):
            state.set_ground(k + j, g)
        n = self.setup.structure.n
        if k == 0:
            x, v = [0.0] * n, [0.0] * n
            self.window_steps = 0
        else:
            x, v, self.window_steps = state.state_at(k - 1)
            if self.state_names:
                self.computational_state = state.recorded_state(x, v, k - 1)
        if not any(self._coupled):
            return
        sampled = state.interface_forces(x, v, self._local_dof)
        predicted = None
        if self._targets:
            tangent = getattr(state, 'tangent', None)
            k_t = tangent() if tangent is not None and k > 0 else None
            self._use_tangent(k_t)
            q, residual = self._prediction_input(k, window, latest, x, v)
            if tangent is not None and k > 0:
                # a part that yields: the mechanisms that go on yielding, unload or start
                # to yield over the predicted motion (core.tangent)
                if self._mechanisms is None:
                    self._mechanisms = YieldMechanisms(
                        self.setup.substructures.stiffness_c_N_per_m,
                        getattr(state, 'virgin_mechanisms', None) or (),
                        self.setup.structure.computational_index)
                deficit = getattr(state, 'deficit_forces', None)
                if deficit is None or not self._mechanisms.uses_deficit:
                    deficit = None                 # (not computed on every step for nothing)
                self._mechanisms.observe(x, k_t, None if deficit is None else deficit(x, v))
                shifted = q[:len(x)]
                stiffness = self._mechanisms.stiffness(
                    [a - b for a, b in zip(self._interface.displacements(q), shifted)])
                if stiffness is not None:
                    self._use_tangent(stiffness)
                    q, residual = self._prediction_input(k, window, latest, x, v)
            predicted = dict(zip(self._targets, self._interface(q)))
            if residual is not None:
                for r, d in zip(self._targets, residual):
                    predicted[r] += d
        for r, mode in enumerate(self._modes):
            if mode is None:
                continue
            if mode == 'sampled':
                self.interface_N[r] = sampled[r]
            elif mode == 'extrapolated':
                weights, hist = self._history[r]
                if k > 0:
                    hist.appendleft(sampled[r])
                self.interface_N[r] = sum(w * h for w, h in zip(weights, hist))
            else:
                self.interface_N[r] = predicted[r]


def below_tangent_floor(block: np.ndarray, initial: np.ndarray) -> bool:
    """Whether a tangent stiffness block is below :data:`TANGENT_FLOOR` of its initial one
    in some direction: ``block - TANGENT_FLOOR * initial`` not positive definite (a Cholesky
    factorization of its symmetric part tells). Both square, the same shape [N/m]."""
    shifted = block - TANGENT_FLOOR * initial
    try:
        np.linalg.cholesky(0.5 * (shifted + shifted.T))
        return False
    except np.linalg.LinAlgError:
        return True


def _floored_tangent(tangent: np.ndarray, k0: np.ndarray, qi) -> np.ndarray:
    """The computational part's tangent stiffness `tangent` (n x n) [N/m], or ``tangent +
    TANGENT_FLOOR * k0`` where its block on the computational DOFs `qi` is below the floor
    (:func:`below_tangent_floor`): a member that yields perfectly plastic leaves its DOFs
    without stiffness, and the prediction's static shift (``K_UU^-1 d_U``,
    ``OpenSeesPart.prediction_state``) without an inverse (:data:`TANGENT_FLOOR`)."""
    if not qi:
        return tangent
    ix = np.ix_(qi, qi)
    if below_tangent_floor(tangent[ix], k0[ix]):
        return tangent + TANGENT_FLOOR * k0
    return tangent


def _forget_before(seen: dict, step: int) -> None:
    """Drop the measurements of samples before `step` from `seen` (step -> measurement)."""
    for old in [j for j in seen if j < step]:
        del seen[old]


def ground_window(lookup: Callable[[int], float], k: int, lookahead_steps: int,
                  n_total: int, following: Sequence[float] = ()) -> list[float]:
    """``[xg''[k], ..., xg''[k + lookahead_steps]]``: the record, then the samples that
    follow a record cut short (`following`), then zeros.

    Parameters
    ----------
    lookup : callable(int) -> float
        Ground acceleration of a step [m/s^2].
    k : int
        Step of the new force.
    lookahead_steps : int >= 0
    n_total : int
        Record length (the run's steps).
    following : sequence of float
        The samples after step ``n_total - 1`` [m/s^2]
        (``GroundMotion.following_m_s2``); zeros after them.
    """
    end = k + lookahead_steps + 1
    if end <= n_total:
        return [float(lookup(j)) for j in range(k, end)]
    after = len(following)
    return [float(lookup(j)) if j < n_total else
            (float(following[j - n_total]) if j - n_total < after else 0.0)
            for j in range(k, end)]
