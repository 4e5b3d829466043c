"""Checks of a run with an OpenSees model before it starts (no rclpy).

* **Where it runs**: the model is stepped by a builder that hears every rig's measured motion:
  the central builder (one host, or a compute host of its own with the rigs across the
  network: ``--partition builder_remote``), or with one rig the builder beside it in its lab
  (``per_rig``, the default partition ``loop_local``). A builder per rig of several rigs
  (each lab integrating a replica of the computational part and predicting the other rigs'
  motion over the network) would need each replica to step the model on predicted motion and
  to roll it back when the measurement comes: refused, in one line.
* **Real time**: a timed dry run of the model (:func:`~seft_ros.opensees.part.dry_run`: 500
  steps, the interfaces moving 1 mm at 2 Hz) must fit: its median step time within
  :data:`~seft_ros.opensees.part.BUDGET_FRACTION` of the sample period, else the run is
  refused in one line (the other half of the period is the builder's own work and the
  messages), or within :data:`~seft_ros.opensees.part.DEFERRED_BUDGET_FRACTION` of it with
  ``step: deferred`` (the model stepped after the builder's command is out); a p99 beyond
  it is a warning (on a loaded host the slowest steps are the scheduler's, not the
  model's).
"""

from typing import Callable

from seft_msgs_py.errors import ParameterError
from seft_ros.opensees.model import KIND
from seft_ros.opensees.part import budget_fraction, dry_run

__all__ = ['check_runs', 'DRY_RUN_STEPS']

#: Steps of the timed dry run.
DRY_RUN_STEPS = 500


def _say_build_messages(sub, name: str, progress: Callable[[str], None]) -> None:
    """Build the whole model once and say, in one line, what OpenSees said while it built (a
    successful build's warnings were dropped: a new user's zeroLength element with its nodes
    3 m apart built without a word; session 38). A model that does not build is refused
    where the run builds it, as before."""
    from seft_ros.opensees.model import ModelError, ModelSpec, build_model
    try:
        said = build_model(ModelSpec.from_doc(sub.structure.model))
    except ModelError:
        return
    if said:
        more = f' (and {len(said) - 1} more line(s))' if len(said) > 1 else ''
        progress(f'note: opensees: {name}: OpenSees said while the model built: '
                 f'{said[0][:240]}{more}')


def _model_name(structure) -> str:
    from seft_ros.opensees.model import model_name
    model = structure.model
    return model_name(model['model'], model.get('function', 'build'))


def check_runs(runs, *, progress: Callable[[str], None] = print) -> None:
    """Refuse runs with an OpenSees model that cannot run as configured (module notes).

    Parameters
    ----------
    runs : list of dict
        The runs' resolved parameters (runs without a model are skipped).
    progress : callable(str)
        Receives one line per dry run, and the warnings.

    Raises
    ------
    ParameterError
        A model of several rigs under ``structure_builders: per_rig``, or a real-time run
        whose model's dry run does not fit the sample period (the figures in the message).
    """
    from seft_ros.core.structure import is_study, test_setup
    timed, built = {}, set()
    for p in runs:
        if is_study(p) or '"opensees"' not in str(p.get('structure', '')):
            continue
        setup = test_setup(p)
        s = setup.structure
        if s.model_kind != KIND:
            continue
        name = _model_name(s)
        if s.to_json() not in built:
            built.add(s.to_json())
            _say_build_messages(setup.substructures, name, progress)
        builders = p.get('structure_builders', 'central')
        if builders != 'central' and len(s.rig_names) > 1:
            raise ParameterError(
                f'parameter structure_builders={builders!r}: the OpenSees model {name} is '
                "stepped on every rig's measured motion by one builder, not as a replica per "
                f"rig ({len(s.rig_names)} rigs); use 'central' (one host, or the builder on a "
                'compute host of its own: --partition builder_remote)')
        if p.get('mode', 'lockstep') != 'realtime':
            continue
        dt = float(p['dt'])
        step = str(s.model.get('step', 'immediate'))
        fraction = budget_fraction(step)
        key = (p['structure'], dt)
        if key not in timed:
            timed[key] = dry_run(setup.substructures, dt, steps=DRY_RUN_STEPS)
            r = timed[key]
            progress(f'opensees: {name}: a dry run of {DRY_RUN_STEPS} steps took p50 '
                     f'{1e3 * r.p50_s:.3f} / p99 {1e3 * r.p99_s:.3f} / max {1e3 * r.max_s:.3f} '
                     f'ms per step (budget {1e3 * fraction * dt:.3f} ms)')
            if r.p99_s > fraction * dt >= r.p50_s:
                progress(f"warning: opensees: {name}: 1 % of the dry run's steps took more "
                         f'than {1e3 * fraction * dt:.3f} ms (p99 {1e3 * r.p99_s:.3f} '
                         'ms): expect late reference forces (a loaded host?)')
        r = timed[key]
        if r.p50_s > fraction * dt:
            raise ParameterError(
                f'structure.opensees: {name}: a timed dry run took {1e3 * r.p50_s:.3f} ms per '
                f'step (median), more than {fraction:g} of the sample period dt = '
                f'{1e3 * dt:g} ms: the model does not fit in real time (fewer substeps, a '
                'coarser model, a longer dt' + (')' if step == 'deferred' else
                                                 ' or step: deferred)'))
