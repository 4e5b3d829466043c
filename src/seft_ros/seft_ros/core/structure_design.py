"""The force-loop inverse of each rig of a structure chosen by rehearsing the test (no rclpy).

``seft design`` (and ``seft identify --params``) design a rig's force controller and the
``model`` compensator's force-loop inverse for the one-DOF test of its specimen: the
inverse's delay is the one whose test is predicted closest to the reference structure
(:func:`seft_ros.core.stability.predicted_error`). In a structure the rig's loop is closed
again through the computational part (the interface force, coupled loop calibrated by
:func:`seft_ros.core.law_calibration.structure_calibration`), and what the delay does there
is not what it does alone: on ``two_story`` with a 32 Hz, 0.5 % first story on the
``valve_2nd_order`` actuator the one-DOF design's 5 steps gave the first story 8 % NRMS
acceleration (a loop pole above the inverse's band, 44 Hz, lightly damped), 12 steps 1.3 %.

:func:`choose_structure_inverses` rehearses the structure's test on the lab's own model of
each rig (``rig_model: state_space`` with its ``plant_model``, never a ``rig_plant_model``:
the test is never chosen on the plant it will run on) for the delays from the shortest
stable one on (:data:`DELAY_SPAN_STEPS` of them, and the one-DOF design's), rig after rig,
on the test's own record (its first :data:`REHEARSAL_S`), in lockstep; it keeps the delay
of the least worst NRMS over every DOF and signal (displacement, acceleration, interface
force), the shorter on a tie.

References
----------
N. Nakata and S. Combs, Substructure Effective Force Testing, Sec. 5 (the delay and its
compensation). J. E. Carrion and B. F. Spencer Jr. (2007), Model-based strategies for
real-time hybrid testing, NSEL Report 006.
"""

from dataclasses import dataclass, field
import json
import math
from typing import Callable, Mapping

from seft_msgs_py.errors import ParameterError

__all__ = ['InverseChoice', 'choose_structure_inverses', 'with_rig_values', 'REHEARSAL_S',
           'DELAY_SPAN_STEPS']

#: The longest stretch of the test's record a rehearsal runs [s].
REHEARSAL_S = 20.0
#: How many inverse delays are rehearsed per rig [steps], from the shortest with which the
#: rig's one-DOF test is stable up to alpha 2 on its model
#: (``ForceLoopDesign.shortest_loop_delay_steps``), which the design may pass over for a
#: longer one predicted better for the one-DOF test. Not from a shorter one: the one-DOF
#: criterion is the design's robustness requirement, and a rehearsal on the model does not
#: show robustness (``pure_delay`` with the 32 Hz, 0.5 % first story of ``two_story``,
#: identified in real time three times: rehearsed at 1.2-2.0 % worst NRMS, run in real time
#: at 0.3-17 % by identification, docs: results/own-actuator).
DELAY_SPAN_STEPS = 16


@dataclass
class InverseChoice:
    """One rig's force-loop inverse chosen for the structure.

    Attributes
    ----------
    rig : str
    designed_steps : int
        The one-DOF design's delay [steps].
    chosen_steps : int
    errors : dict of int to float
        Each rehearsed delay's worst NRMS over every DOF and signal [-] (``inf``: unstable
        or refused, with the reason in `refused`).
    refused : dict of int to str
    values : dict
        The rig's parameters for the chosen delay (``predictor_loop_delay_steps`` and, when
        the design gave one, ``predictor_tau_s`` moved by as many steps as the delay is
        longer than the design's; kept for a shorter one) and
        ``predictor_loop_rehearsed`` true (the pre-run line of
        :func:`~seft_ros.core.specimen_settings.costly_settings` is then not said).
    """

    rig: str
    designed_steps: int
    chosen_steps: int
    errors: dict = field(default_factory=dict)
    refused: dict = field(default_factory=dict)
    values: dict = field(default_factory=dict)

    def summary(self) -> str:
        """One line: the choice and the rehearsed errors it rests on."""
        chosen = self.errors.get(self.chosen_steps, math.inf)
        designed = self.errors.get(self.designed_steps, math.inf)
        label = f'rig {self.rig}: ' if self.rig else ''
        return (f'{label}force-loop inverse {self.chosen_steps} steps for the structure '
                f'(rehearsed on the plant model, worst NRMS {_percent(chosen)} over every DOF '
                f"and signal; the one-DOF design's {self.designed_steps} steps: "
                f'{_percent(designed)}; {len(self.errors)} delays tried)')

    def to_json(self) -> dict:
        """The choice and every delay's rehearsed error (``None``: unstable or refused)."""
        return {'designed_steps': self.designed_steps, 'chosen_steps': self.chosen_steps,
                'worst_nrms': {str(d): (e if math.isfinite(e) else None)
                               for d, e in self.errors.items()},
                'refused': {str(d): r for d, r in self.refused.items()}}


def _percent(value: float) -> str:
    return f'{100 * value:.2f} %' if math.isfinite(value) else 'unstable or refused'


def with_rig_values(params: Mapping, rig: str, values: Mapping) -> dict:
    """`params` with `values` set in rig `rig`'s section of the structure.

    Parameters
    ----------
    params : mapping
        A structure run's resolved parameters (``structure`` the JSON of the structure, its
        ``rigs`` the per-rig sections).
    rig : str
    values : mapping
        Parameter name -> value as the nodes take it (mappings as JSON text).

    Returns
    -------
    dict

    Raises
    ------
    ParameterError
        Not a structure, or no such rig.
    """
    text = params.get('structure', 'none')
    if not isinstance(text, str) or text == 'none':
        raise ParameterError('structure design: expected a structure')
    structure = json.loads(text)
    rigs = structure.setdefault('rigs', {})
    if rig not in rigs:
        raise ParameterError(f'structure design: no rig {rig!r} (rigs: {", ".join(rigs)})')
    rigs[rig] = dict(rigs[rig], **values)
    return dict(params, structure=json.dumps(structure, sort_keys=True))


def _worst_error(params: Mapping) -> float:
    """The rehearsal's worst NRMS over every DOF and signal (``inf`` if unstable)."""
    from seft_ros.analysis.metrics import compare_run
    from seft_ros.core.experiment import simulate
    run = simulate(params)
    if not run.stable:
        return math.inf
    comparison = compare_run(run)
    worst = [comparison.worst_nrms(signal)
             for signal in ('displacement', 'acceleration', 'interface_force')]
    worst = [w for w in worst if math.isfinite(w)]
    return max(worst) if worst else math.inf


def _no_rehearsal_clause(choice: InverseChoice, setup) -> str:
    """How the rehearsals of `choice` failed, for the one line of a design that found no
    stable one: how many went unstable (with the structure's natural frequencies [Hz], the
    modes such a test loses) and how many were refused (with the first refusal's reason)."""
    refused = len(choice.refused)
    unstable = len(choice.errors) - refused
    parts = []
    if unstable:
        freqs = ', '.join(f'{f:.3g}' for f in setup.substructures.structure.modes()[0])
        parts.append(f"{unstable} unstable; the structure's modes at {freqs} Hz")
    if refused:
        parts.append(f'{refused} refused: {next(iter(choice.refused.values()))}')
    return f' ({"; ".join(parts)})'


def choose_structure_inverses(params: Mapping, designed: Mapping[str, Mapping],
                              progress: Callable[[str], None] = lambda _: None,
                              shortest: Mapping[str, int] | None = None
                              ) -> list[InverseChoice]:
    """Each coupled rig's force-loop inverse delay chosen by rehearsing the structure (module
    notes).

    Parameters
    ----------
    params : mapping
        The structure run's resolved parameters.
    designed : mapping of str to mapping
        Per rig, the one-DOF design's parameters as the nodes take them (``seft design``'s:
        ``force_controller_tf``, ``predictor_loop_*``, ``predictor_calibration``,
        ``predictor_tau_s``); the rigs not in it are rehearsed as they are.
    progress : callable(str), optional
        Receives a line per rig as its rehearsals start.
    shortest : mapping of str to int, optional
        Per rig, the shortest stable inverse delay of its design
        (``ForceLoopDesign.shortest_loop_delay_steps``,
        :class:`~seft_ros.core.force_design.ForceLoopDesign`):
        the rehearsals start there (default, or 0: at the one-DOF design's delay).

    Returns
    -------
    list of InverseChoice
        One per rig of `designed` with ``predictor: model`` whose DOF carries computational
        springs or dashpots (empty for the study's test).

    Raises
    ------
    ParameterError
        As :func:`with_rig_values`, or a rig for which no rehearsed delay was stable.
    """
    from seft_ros.core.force_loop import has_plant_model
    from seft_ros.core.structure import test_setup
    setup = test_setup(params)
    if setup.is_study:
        return []
    base = dict(params, duration_s=min(float(params.get('duration_s') or REHEARSAL_S),
                                       REHEARSAL_S))
    for rig, values in designed.items():
        base = with_rig_values(base, rig, values)
    setup = test_setup(base)
    rigs = [r for r in setup.substructures.coupled_rigs
            if r in designed and setup.rig_params[r].get('predictor') == 'model']
    for rig in setup.rig_names:      # rehearsed on the lab's model of each rig
        if has_plant_model(setup.rig_params[rig]):      # that model, not a rig_plant_model
            base = with_rig_values(base, rig, {'rig_model': 'state_space',
                                               'rig_plant_model': 'none'})
    choices = []
    for rig in rigs:
        rp = setup.rig_params[rig]
        designed_steps = int(rp['predictor_loop_delay_steps'])
        first = min(designed_steps, int((shortest or {}).get(rig) or designed_steps))
        last = first + DELAY_SPAN_STEPS - 1
        delays = sorted(set(range(first, last + 1)) | {designed_steps})
        tau = float(rp.get('predictor_tau_s', 0.0) or 0.0)
        dt = float(params['dt'])
        progress(f'rig {rig}: rehearsing the structure with force-loop inverses of '
                 f'{first}-{last} steps' + (f' and {designed_steps}' if designed_steps > last
                                            else ''))
        choice = InverseChoice(rig, designed_steps, designed_steps)

        def delay_values(d):
            values = {'predictor_loop_delay_steps': d}
            if tau > 0:             # the closed loop's delay moves with a longer inverse's
                values['predictor_tau_s'] = tau + max(d - designed_steps, 0) * dt
            return values
        for d in delays:
            try:
                choice.errors[d] = _worst_error(with_rig_values(base, rig, delay_values(d)))
            except ParameterError as exc:
                choice.errors[d] = math.inf
                choice.refused[d] = str(exc)
        best = min(choice.errors, key=lambda d: (choice.errors[d], d))
        if not math.isfinite(choice.errors[best]):
            raise ParameterError(f'rig {rig}: no force-loop inverse of {first}-'
                                 f'{max(last, designed_steps)} steps gave a stable '
                                 'rehearsal of the structure on its plant model'
                                 + _no_rehearsal_clause(choice, setup))
        choice.chosen_steps = best
        choice.values = dict(delay_values(best), predictor_loop_rehearsed=True)
        base = with_rig_values(base, rig, choice.values)
        choices.append(choice)
    return choices
