"""Settings that follow the specimen, and the combinations the docs show cost accuracy.

A member that yields needs its own force controller, restoring-force model and force-loop
inverse (docs: a member that yields; structures): with the settings of an elastic specimen
the two piers with a yielding pier at 700 N err by 300-1000 % and the monitor may call it
stable. When a rig's specimen is declared to yield (``specimen_model: bouc_wen``),
:func:`follow_specimen` chooses :data:`YIELDING_SETTINGS` for it, each unless the user set it
(in the configuration, a ``--params`` file, ``--set`` or the rig's section), and says which it
chose. :func:`costly_settings` gives one line per run for a combination the docs' own tables
show costs accuracy (:data:`COSTLY`), whoever chose it.
"""

import json
from typing import Any, Mapping

from seft_msgs_py.parameters import identification_run

__all__ = ['YIELDING_SETTINGS', 'follow_specimen', 'costly_settings', 'COSTLY', 'FLAGGING',
           'CANCELLED_STIFFNESS_TOLERANCE', 'CANCELLED_DAMPING_TOLERANCE',
           'PLANT_SPECIMEN_TOLERANCE']

#: The settings of a member that yields: (parameter, value, the rig model it applies to, None:
#: every rig). docs/tutorials/yielding.md (the tangent controller and the hysteretic
#: compensator) and docs/structures.md (a force-loop inverse of 5 steps, 48 taps, weight 1e-3:
#: on the two piers with a yielding pier at 700 N, 5 steps 0.9-1.4 % per DOF, 10 steps 9.7 %,
#: 14 steps 17 %; on one rig, the default record at alpha 1 / 1.5, 1.5 % where 10 steps gives
#: 2.4-2.7 %).
YIELDING_SETTINGS = (
    ('force_controller', 'tangent_loop_shaping', 'servohydraulic'),
    ('predictor_restoring_force', 'hysteretic', None),
    ('predictor_loop_delay_steps', 5, 'servohydraulic'),
    ('predictor_loop_taps', 48, 'servohydraulic'),
    ('predictor_loop_hf_weight', 1e-3, 'servohydraulic'),
)


def _yields(params: Mapping[str, Any]) -> bool:
    return params.get('specimen_model', 'linear') != 'linear'


def _choose(rig_model: str, is_set) -> dict[str, Any]:
    """The yielding member's settings for a rig of `rig_model` that `is_set(name)` says the
    user did not set."""
    return {name: value for name, value, rig in YIELDING_SETTINGS
            if (rig is None or rig == rig_model) and not is_set(name)}


def _note(who: str, chosen: dict[str, Any]) -> str:
    settings = ', '.join(f'{k} {v:g}' if isinstance(v, float) else f'{k} {v}'
                         for k, v in chosen.items())
    return (f'{who}: specimen_model bouc_wen (a member that yields): chose {settings} (the '
            'settings for a yielding member, docs: structures); set any of them to choose '
            'otherwise')


def follow_specimen(config: Mapping[str, Any], params: dict[str, Any]
                    ) -> tuple[dict[str, Any], list[str]]:
    """A run's parameters with the settings of a member that yields chosen for each rig whose
    specimen is declared to yield, unless the user set them.

    Parameters
    ----------
    config : mapping
        What the user set for the whole test: the configuration, ``--params`` files and
        command line, before the defaults (a name here is set for every rig).
    params : dict
        The run's resolved parameters (the study's, or with a ``structure`` whose rig
        sections hold what the user set for each rig).

    Returns
    -------
    (dict, list of str)
        The parameters (`params` itself when nothing was chosen) and one line per rig
        naming what was chosen.
    """
    structure = params.get('structure', 'none')
    if structure in ('none', '', None):
        if not _yields(params):
            return params, []
        chosen = _choose(params.get('rig_model'), lambda name: name in config)
        if not chosen:
            return params, []
        return dict(params, **chosen), [_note('rig', chosen)]
    doc = json.loads(structure)
    rigs = doc.get('rigs') or {}
    notes = []
    for rig, section in rigs.items():
        merged = {**params, **section}
        if not _yields(merged):
            continue
        chosen = _choose(merged.get('rig_model'),
                         lambda name, s=section: name in s or name in config)
        if chosen:
            section.update(chosen)
            notes.append(_note(rig, chosen))
    if not notes:
        return params, []
    return dict(params, structure=json.dumps(doc, sort_keys=True)), notes


#: The study's ``loop_shaping`` cancels its own specimen, ``s^2 + 17.14 s + 4002`` (paper Eq.
#: 3.1); a linear specimen whose k/m is further than this (relative) from 4002 s^-2 gets the
#: ``'specimen'`` line. Measured on the one-rig servohydraulic test (embedded record, 1000 N,
#: 20 s, displacement NRMS, alpha 1 ``model`` / ``adaptive``, alpha 0 ``none``) against the
#: stiffness ratio to the study's 2.11e5 N/m (``specimen_loop_shaping``, the rig's own C_f:
#: 0.36-0.51 % and 2.35-2.63 % at every ratio): 0.995: 0.50 / 1.87 %; 1.0 (4003.8 s^-2,
#: 0.045 % off): 0.40 / 2.48 %; 1.005: 0.92 / 3.25 %; 1.01: 1.52 / 4.10 %; 0.98 / 1.02: 2.3 /
#: 2.8 %; 0.95 / 1.05: 5.9 / 6.5 %; 0.9 / 1.1: 11.8 / 12.7 %; 0.8 / 1.2: 22.6 / 25.4 %. Past
#: 0.5 % the compensated test errs more than twice as much as with its own controller.
CANCELLED_STIFFNESS_TOLERANCE = 0.005
#: The same for c/m against 17.14 s^-1 (the damping ratio; ``model`` at alpha 1 against the
#: damping ratio to the study's 903.278 N s/m, ``loop_shaping`` / ``specimen_loop_shaping``):
#: 0.98: 1.12 / 0.37 %; 1.02: 0.42 / 0.36 %; 0.95: 2.36 / 0.38 %; 1.05: 1.34 / 0.35 %;
#: 0.9 / 1.1: 4.8 / 2.7 %; 0.8: 11.4 %; 0.5: 57 %. c/m matters a quarter as much as k/m: at the
#: specimen's resonance the uncancelled residual is ``Delta(k/m) + j w Delta(c/m)``, and 0.5 %
#: of k/m is 1.8 % of ``w c/m`` there.
CANCELLED_DAMPING_TOLERANCE = 0.02

#: The docs' measured costs of a setting, by rule (:func:`costly_settings`).
COSTLY = {
    'controller': ('force_controller {force_controller} on a member that yields: its loop '
                   "loses the member as it softens (the study's loop shaping 43.6 % at alpha "
                   '0, docs: a member that yields); tangent_loop_shaping follows it'),
    'linear law': ('predictor {predictor} with predictor_restoring_force model on a member '
                   'that yields: the linear law with the elastic k runs away (the stroke '
                   'limit from alpha 0.5, docs: a member that yields); use hysteretic'),
    'tangent law': ('predictor model with predictor_restoring_force measured on a member '
                    'that yields: 8.7-18.6 % where hysteretic gives 0.2-0.9 % (docs: a member '
                    'that yields)'),
    'loop inverse': ('a force-loop inverse of {predictor_loop_delay_steps} steps on a member '
                     'that yields: the two piers with a yielding pier lose 9.7 % at 10 steps '
                     'and 17 % at 14, 1.4 % at 5 (docs: results/robustness, part 3)'),
    'model unknown': ('predictor model with specimen_uncertainty {specimen_uncertainty:g}: '
                      'model needs the specimen as it is (10 % off costs the structures '
                      '4-65 %, docs: results/robustness); adaptive identifies it'),
    'latency declared': ('predictor adaptive with adaptive_loop {adaptive_loop}: the force '
                         "loop's I/O latency as declared; 10 % off it costs 2-2.7 % (the "
                         'two piers, the one-rig test), 20 % off up to 5.4 % (docs: '
                         'results/robustness); adaptive_loop: model_latency (the default, '
                         'auto) identifies it'),
    'one-DOF inverse': ('predictor {predictor} with predictor_calibration poles and the '
                        'force-loop inverse chosen for the one-DOF test '
                        "({predictor_loop_delay_steps} steps, seft identify's) on a DOF "
                        'coupled to the computational part: seft design CONFIG --out FILE '
                        "chooses it by rehearsing the structure on the rig's plant model "
                        '(two_story with a 32 Hz first story: its acceleration 8.0 % with '
                        "the one-DOF choice, 1.2-1.3 % with the structure's; docs: "
                        'results/own-actuator)'),
    'structure inverse': ('predictor {predictor} on a DOF coupled to the computational part '
                          "with the default force-loop inverse ({predictor_loop_delay_steps} "
                          'steps, {predictor_loop_taps} taps), not chosen for the structure: '
                          'seft design CONFIG --out FILE chooses it by rehearsing the '
                          "structure on the rig's model (a new user's OpenSees steel frame "
                          'erred 4.27 % of x with the default, 1.63 % with the 5 steps the '
                          'shipped file sets; session 38)'),
    'specimen': ("force_controller loop_shaping cancels the study's specimen (s^2 + 17.14 s + "
                 "4002, {cancelled_hz:.2f} Hz), this rig's is s^2 + {c_per_m:.4g} s + "
                 '{k_per_m:.5g} ({specimen_hz:.2f} Hz): 1 % stiffer costs the one-rig test 1.5 % '
                 'of x where it had 0.4 %, 18 % stiffer a two-story 24.7 % where it had 0.49 % '
                 '(docs: structures); use force_controller: specimen_loop_shaping'),
    'plant specimen': ("the declared specimen ({mass_kg:.4g} kg, {stiffness_N_per_m:.4g} N/m, "
                       "{declared_hz:.2f} Hz) is {mass_ratio:.3g} x the plant model's mass and "
                       '{stiffness_ratio:.3g} x its stiffness ({plant_mass_kg:.4g} kg, '
                       '{plant_stiffness_N_per_m:.4g} N/m, {plant_hz:.2f} Hz): the reference '
                       'structure, the guard and the compensators take the declared specimen, '
                       "the force loop the plant model's (a unit slip? a plant model of "
                       'another specimen?); declare the specimen the plant model has (seft '
                       'identify wrote it), or identify this one'),
    'uncompensated structure': ("predictor none on a structure: the force loop's lag is not "
                                'compensated, and no error flag judges the run (a two-story '
                                'whose uncompensated run completed erred 37 % of x; session '
                                "36); 'model' or 'adaptive' compensate it"),
    'uncompensated': ("predictor none at alpha {alpha:g}: the force loop's lag is not "
                      "compensated (the study's finding: on its rig it costs 35-49 % at alpha "
                      '0.5-1 and is unstable near 1.5, README: the main job; the guard gives '
                      "this rig's figures); 'model' or 'adaptive' compensate it"),
}


#: The rules of :data:`COSTLY` that flag a run that used them (the study's own finding, an
#: uncompensated test, is run to be shown, and a declared latency costs only where it is
#: wrong: said before the run, not flagged).
FLAGGING = ('controller', 'linear law', 'tangent law', 'loop inverse', 'model unknown',
            'specimen')


#: A rig's declared specimen whose mass or stiffness is further than this (relative) from
#: its plant model's specimen gets the ``'plant specimen'`` line: a new user's mass typed in
#: grams (80000 kg against the plant model's 80 kg) was refused by the guard (largest stable
#: alpha 0.000742) with no word of the cause (session 38). A prior 20 % off is given as
#: ``predictor_*``, not as the rig's specimen.
PLANT_SPECIMEN_TOLERANCE = 0.1


def _plant_specimen(p: Mapping[str, Any]) -> dict[str, float] | None:
    """The figures of the ``'plant specimen'`` line when a rig's declared specimen
    (``mass_kg``, ``stiffness_N_per_m``) is not its plant model's
    (:data:`PLANT_SPECIMEN_TOLERANCE`; :func:`~seft_ros.core.force_loop.force_loop_plant`),
    else None (no plant model, or one without a specimen)."""
    import math

    from seft_msgs_py.errors import ParameterError
    from seft_ros.core.force_loop import force_loop_plant, has_plant_model

    if not has_plant_model(p):
        return None
    try:
        spec = force_loop_plant(p).specimen
        m, k = float(p['mass_kg']), float(p['stiffness_N_per_m'])
    except (ParameterError, KeyError, TypeError, ValueError):
        return None                         # refused elsewhere
    if spec is None or not (m > 0 and k > 0):
        return None
    ratios = spec.mismatch(m, k, PLANT_SPECIMEN_TOLERANCE)
    if ratios is None:
        return None
    mass_ratio, stiffness_ratio = ratios
    return {'declared_hz': math.sqrt(k / m) / (2.0 * math.pi), 'mass_ratio': mass_ratio,
            'stiffness_ratio': stiffness_ratio, 'plant_mass_kg': spec.mass_kg,
            'plant_stiffness_N_per_m': spec.stiffness_N_per_m,
            'plant_hz': spec.natural_frequency_hz}


#: The force-loop inverse's settings (the ``'structure inverse'`` line: all at their
#: defaults, none chosen).
_LOOP_INVERSE = ('predictor_loop_delay_steps', 'predictor_loop_taps', 'predictor_loop_hf_weight')


def _cancelled(p: Mapping[str, Any]) -> dict[str, float] | None:
    """The figures of the ``'specimen'`` line when a rig's linear specimen is not the one its
    ``loop_shaping`` C_f cancels (:data:`CANCELLED_STIFFNESS_TOLERANCE`,
    :data:`CANCELLED_DAMPING_TOLERANCE`), else None."""
    import math

    from seft_msgs_py.errors import ParameterError
    from seft_ros.core.controller import LOOP_SHAPING_DEN, specimen_denominator

    try:
        _, c_per_m, k_per_m = specimen_denominator(p)    # what specimen_loop_shaping cancels
    except ParameterError:
        return None                         # refused elsewhere
    if not c_per_m >= 0:
        return None
    _, c0, k0 = LOOP_SHAPING_DEN
    if (abs(k_per_m / k0 - 1.0) <= CANCELLED_STIFFNESS_TOLERANCE
            and abs(c_per_m / c0 - 1.0) <= CANCELLED_DAMPING_TOLERANCE):
        return None
    return {'k_per_m': k_per_m, 'c_per_m': c_per_m,
            'specimen_hz': math.sqrt(k_per_m) / (2.0 * math.pi),
            'cancelled_hz': math.sqrt(k0) / (2.0 * math.pi)}


def costly_settings(params: Mapping[str, Any], *, flagging: bool = False) -> list[str]:
    """One line per rig and combination of a run's settings that the docs' tables show
    costs accuracy (:data:`COSTLY`), ``'<rig>: <why>'``; `flagging`: only the rules that flag
    the run (:data:`FLAGGING`). None for a rig of an open-loop identification run
    (:func:`~seft_ros.core.monitor.open_loop_identification`: its controller and
    compensator drive nothing).

    Raises
    ------
    ParameterError
        An invalid structure (as :func:`~seft_ros.core.structure.test_setup`).
    """
    from seft_msgs_py.parameters import defaults as schema_defaults
    from seft_ros.core.force_loop import has_plant_model
    from seft_ros.core.monitor import open_loop_identification
    from seft_ros.core.predictors import adaptive_loop_mode
    from seft_ros.core.structure import is_study, test_setup
    coupled = ()
    defaults = schema_defaults()
    if is_study(params):
        rigs = {'rig': params}
    else:
        setup = test_setup(params)
        rigs = {r: setup.rig_params[r] for r in setup.rig_names}
        coupled = setup.substructures.coupled_rigs      # as seft design rehearses them
    lines = []
    for rig, p in rigs.items():
        if open_loop_identification(p):
            # the valve is driven directly: the force controller is bypassed and the
            # reference force (the compensator's) drives nothing, so no rule applies
            continue
        rules = []
        predictor = p.get('predictor')
        restoring = p.get('predictor_restoring_force', 'model')
        servo = p.get('rig_model') == 'servohydraulic'
        if _yields(p):
            if servo and p.get('force_controller') != 'tangent_loop_shaping':
                rules.append('controller')
            if predictor in ('model', 'adaptive', 'ats') and restoring == 'model':
                rules.append('linear law')
            if predictor == 'model' and restoring == 'measured':
                rules.append('tangent law')
            if (servo and predictor in ('model', 'adaptive') and restoring != 'model'
                    and int(p.get('predictor_loop_delay_steps', 5)) > 5):
                rules.append('loop inverse')
        elif predictor == 'model' and float(p.get('specimen_uncertainty', 0) or 0) >= 0.1:
            rules.append('model unknown')
        figures = {}
        if (servo and not _yields(p)
                and p.get('force_controller', 'loop_shaping') == 'loop_shaping'):
            figures = _cancelled(p) or {}
            if figures:
                rules.append('specimen')
        plant = _plant_specimen(p)
        if plant:
            figures = dict(figures, **plant)
            rules.append('plant specimen')
        if (servo and predictor == 'adaptive' and not _yields(p)
                and adaptive_loop_mode(p) == 'model' and not has_plant_model(p)):
            rules.append('latency declared')
        if (rig in coupled and predictor in ('model', 'adaptive')
                and p.get('predictor_calibration') == 'poles'
                and not p.get('predictor_loop_rehearsed', False)):
            rules.append('one-DOF inverse')
        if (rig in coupled and servo and predictor in ('model', 'adaptive')
                and p.get('predictor_calibration') != 'poles'
                and not p.get('predictor_loop_rehearsed', False)
                and all(p.get(k) == defaults[k] for k in _LOOP_INVERSE)):
            rules.append('structure inverse')
        if (is_study(params) and predictor == 'none' and float(p.get('alpha', 0)) >= 0.5
                and not identification_run(p)):
            rules.append('uncompensated')
        if (not is_study(params) and predictor == 'none'
                and not identification_run(p)):
            rules.append('uncompensated structure')
        lines += [f'{rig}: {COSTLY[r].format(**p, **figures)}' for r in rules
                  if not flagging or r in FLAGGING]
    return lines
