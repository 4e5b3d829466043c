"""Checks of a run with an OpenSees model before it starts (no rclpy).

* **Where it runs**: the model is stepped by the builder that hears every rig's measured
  motion (``structure_builders: central``: on one host, or on a compute host of its own with
  the rigs across the network). A builder per rig (``per_rig``, each lab integrating a replica
  of the computational part and predicting the other rigs' motion over the network) would
  need each replica to step the model on predicted motion and to roll it back when the
  measurement comes: refused, in one line.
* **Real time**: a timed dry run of the model (:func:`~seft_ros.opensees.part.dry_run`: 500
  steps, the interfaces moving 1 mm at 2 Hz) must fit: its p99 step time within
  :data:`~seft_ros.opensees.part.BUDGET_FRACTION` of the sample period, else the run is
  refused in one line (the other half of the period is the builder's own work and the
  messages).
"""

from typing import Callable

from seft_msgs_py.errors import ParameterError
from seft_ros.opensees.part import BUDGET_FRACTION, dry_run

__all__ = ['check_runs', 'DRY_RUN_STEPS']

#: Steps of the timed dry run.
DRY_RUN_STEPS = 500


def _model_name(structure) -> str:
    from pathlib import Path
    model = structure.opensees
    return f'{Path(model["model"]).name}:{model.get("function", "build")}'


def check_runs(runs, *, progress: Callable[[str], None] = print) -> None:
    """Refuse runs with an OpenSees model that cannot run as configured (module notes).

    Parameters
    ----------
    runs : list of dict
        The runs' resolved parameters (runs without a model are skipped).
    progress : callable(str)
        Receives one line per dry run.

    Raises
    ------
    ParameterError
        A model under ``structure_builders: per_rig``, or a real-time run whose model's dry
        run does not fit the sample period (the figures in the message).
    """
    from seft_ros.core.structure import is_study, test_setup
    timed = {}
    for p in runs:
        if is_study(p) or '"opensees"' not in str(p.get('structure', '')):
            continue
        setup = test_setup(p)
        s = setup.structure
        if s.opensees is None:
            continue
        name = _model_name(s)
        if p.get('structure_builders', 'central') != 'central':
            raise ParameterError(
                f'parameter structure_builders={p["structure_builders"]!r}: the OpenSees model '
                f"{name} is stepped on every rig's measured motion by one builder; use "
                "'central' (one host, or the builder on a compute host of its own)")
        if p.get('mode', 'lockstep') != 'realtime':
            continue
        dt = float(p['dt'])
        key = (p['structure'], dt)
        if key not in timed:
            timed[key] = dry_run(setup.substructures, dt, steps=DRY_RUN_STEPS)
            r = timed[key]
            progress(f'opensees: {name}: a dry run of {DRY_RUN_STEPS} steps took p50 '
                     f'{1e3 * r.p50_s:.3f} / p99 {1e3 * r.p99_s:.3f} / max {1e3 * r.max_s:.3f} '
                     f'ms per step (budget {1e3 * BUDGET_FRACTION * dt:.3f} ms)')
        r = timed[key]
        if r.p99_s > BUDGET_FRACTION * dt:
            raise ParameterError(
                f'structure.opensees: {name}: a timed dry run took p99 {1e3 * r.p99_s:.3f} ms '
                f'per step, more than {BUDGET_FRACTION:g} of the sample period dt = '
                f'{1e3 * dt:g} ms: the model does not fit in real time (fewer substeps, a '
                'coarser model or a longer dt)')
