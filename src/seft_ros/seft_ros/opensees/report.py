"""What a run's report says about its OpenSees model: step times, overruns, hysteresis (no
rclpy, no pyplot: Agg canvas on ``matplotlib.figure.Figure``).

The analysis calls :func:`opensees_entry` (the plug-in's ``summary``,
:mod:`seft_ros.opensees.plugin`) where it forms a run's summary entry
(:func:`seft_ros.analysis.metrics.summary_entry`, key ``'opensees'``) and
:func:`opensees_markdown` (its ``markdown``) where it writes a structure run's section of the
report (:mod:`seft_ros.analysis.report`), for a structure with an ``opensees`` model.
"""

import math
from pathlib import Path
import time
from typing import Any

import numpy as np

from seft_ros.opensees.model import ModelSpec
from seft_ros.opensees.part import PUSH_LIMIT_M, STEP_TIME, budget_fraction, element_names
from seft_ros.opensees.probe import describe_mechanisms, probe_yield, pushover_skipped

__all__ = ['opensees_entry', 'opensees_markdown', 'hysteresis_figure', 'step_time_summary',
           'pushover_entry', 'pushover_lines', 'run_pushover']

def step_time_summary(step_times_s, dt: float, step: str = 'immediate') -> dict[str, Any]:
    """p50, p99 and max of the OpenSees step times [s], and the overruns: steps longer than
    the budget a real-time run is refused against (``budget_fraction(step) dt``) and than
    ``dt``.

    Parameters
    ----------
    step_times_s : array_like (n,)
        Each step's wall time [s] (NaN: none).
    dt : float > 0
        Control period [s].
    step : str
        The model section's ``step`` (``immediate`` or ``deferred``).
    """
    t = np.asarray(step_times_s, dtype=float)
    t = t[np.isfinite(t)]
    budget_s = budget_fraction(step) * dt
    if t.size == 0:
        return {'steps': 0}
    return {'steps': int(t.size), 'p50_s': float(np.percentile(t, 50)),
            'p99_s': float(np.percentile(t, 99)), 'max_s': float(np.max(t)),
            'budget_s': budget_s, 'over_budget': int(np.sum(t > budget_s)),
            'over_period': int(np.sum(t > dt))}


def opensees_entry(run) -> dict[str, Any]:
    """The ``'opensees'`` entry of a run's summary: the model, its substeps and
    :func:`step_time_summary` of the recorded step times.

    Parameters
    ----------
    run : RunData
        A run whose structure has an OpenSees model.
    """
    from seft_ros.core.structure import Structure
    structure = Structure.from_json(run.params['structure'])
    model = structure.model
    from seft_ros.opensees.model import model_name
    step = str(model.get('step', 'immediate'))
    entry = {'model': model_name(model['model'], model.get('function', 'build')),
             'substeps': int(model.get('substeps', 1)),
             'step': step,
             'step_time': step_time_summary(run.computational.get(STEP_TIME, ()),
                                            float(run.params['dt']), step),
             'pushover': run_pushover(run)}
    return entry


def run_pushover(run) -> dict[str, Any]:
    """The pushover entry of a run: what its part found before the test, as the run's data
    carry it (``RunData.extra['part_findings']``: ``seft simulate``'s builder, or the
    builder's final status in the bag); for a run recorded without it (a bag of before
    session 32, or a builder that never reported its end), :func:`pushover_entry` runs the
    pushover again on the model (deterministic, the same entry but its time).

    Parameters
    ----------
    run : RunData
        A run whose structure has an OpenSees model.

    Raises
    ------
    ModelError
        Recorded without it, and the model does not build (OpenSees' message).
    """
    found = (run.extra or {}).get('part_findings') or {}
    if isinstance(found.get('pushover'), dict):
        return found['pushover']
    return pushover_entry(run.params)


def pushover_entry(params) -> dict[str, Any]:
    """What the OpenSees part's pushover before the test finds
    (:func:`~seft_ros.opensees.probe.probe_yield`, run here on the model: it is
    deterministic), for a run's summary when the run's data do not carry it
    (:func:`run_pushover`); the mechanisms as
    :func:`~seft_ros.opensees.probe.describe_mechanisms` gives them.

    Parameters
    ----------
    params : mapping
        A run's parameters with an OpenSees structure.

    Returns
    -------
    dict
        ``{'ran': False, 'why': str}`` (``prediction: initial``, or ``pushover: false``),
        or ``{'ran': True, 'time_s': float, 'mechanisms': [{'coordinate': {dof: weight},
        'first_yield_m': [low, high], 'lost_stiffness_N_per_m': float, 'bilinear': bool}]}``.

    Raises
    ------
    ModelError
        The model does not build (OpenSees' message).
    """
    from seft_ros.core.structure import test_setup
    setup = test_setup(params)
    structure = setup.structure
    spec = ModelSpec.from_doc(structure.model)
    skipped = pushover_skipped(spec)
    if skipped is not None:
        return {'ran': False, 'why': skipped}
    t0 = time.perf_counter()
    mechanisms, _ = probe_yield(spec, setup.substructures.stiffness_c_N_per_m,
                                [PUSH_LIMIT_M] * structure.n)
    found = describe_mechanisms(mechanisms, structure.dofs)
    return {'ran': True, 'time_s': time.perf_counter() - t0, 'mechanisms': found}


def _coordinate(weights: dict) -> str:
    """``-floor_1 + floor_2`` from ``{'floor_1': -1.0, 'floor_2': 1.0}`` (the DOFs'
    order)."""
    text = ''
    for name, w in weights.items():
        sign = '-' if w < 0.0 else '+'
        size = '' if abs(abs(w) - 1.0) < 1e-9 else f'{abs(w):.3g} '
        text += (f' {sign} ' if text else ('-' if w < 0.0 else '')) + size + name
    return text


def pushover_lines(pushover: dict) -> list[str]:
    """Plain-text lines of :func:`pushover_entry`'s entry: one for the pushover, one per
    mechanism (empty list: no entry)."""
    if not pushover:
        return []
    if not pushover.get('ran'):
        return [f'OpenSees pushover: not run ({pushover.get("why")})']
    found = pushover.get('mechanisms') or []
    took = f'{pushover["time_s"]:.2f} s'
    if not found:
        return [f'OpenSees pushover ({took}): no member yields within a push of '
                f'{PUSH_LIMIT_M:g} m on each DOF']
    lines = [f'OpenSees pushover ({took}): {len(found)} yielding mechanism(s)']
    for m in found:
        ends = ' / '.join('-' if v is None else f'{1e3 * v:+.2f}' for v in m['first_yield_m'])
        lines.append(f'  {_coordinate(m["coordinate"])}: first yields at {ends} mm, '
                     + (f'bilinear (loses {m["lost_stiffness_N_per_m"]:.4g} N/m): its first '
                        'yield anticipated' if m['bilinear'] else
                        'gradually: followed from its tangent, not anticipated'))
    return lines


def hysteresis_figure(run, reference, tag: int, path, *, title: str = ''):
    """Draw an element's hysteresis in the test and in the reference (its force against its
    deformation: a beam-column's end moment against its basic rotation, a link's basic force
    against its deformation).

    Parameters
    ----------
    run : RunData
        With the element's recorded states (:func:`~seft_ros.opensees.part.element_names`).
    reference : seft_ros.analysis.reference.StructureReference
        With the element's responses.
    tag : int
    path : path
        The PNG to write.
    title : str

    Returns
    -------
    Path
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    force_name, deformation_name = element_names(tag)
    fig = Figure(figsize=(6.0, 4.5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    if tag in reference.element_forces:
        ax.plot(reference.element_deformations[tag], reference.element_forces[tag],
                color='0.6', lw=2.0, label='reference (OpenSees, whole structure)')
    if force_name in run.computational:
        ax.plot(run.computational[deformation_name], run.computational[force_name],
                color='C0', lw=0.8, label='test (computational part)')
    # a beam-column's rotation and moment at end i; a link's (zeroLength) basic ones
    ax.set_xlabel(f'element {tag}: deformation [rad; a link: m]')
    ax.set_ylabel(f'element {tag}: force [N m; a link: N]')
    ax.grid(True, alpha=0.3)
    ax.legend(loc='best', fontsize='small')
    if title:
        ax.set_title(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    return path


def _ms(value) -> str:
    return '–' if value is None or not math.isfinite(value) else f'{1e3 * value:.3f}'


def opensees_markdown(index: int, run, entry: dict, out_dir, reference=None) -> list[str]:
    """The report's lines on a run's OpenSees model: its step times and overruns, and the
    hysteresis of each recorded element (test against reference).

    Parameters
    ----------
    index : int
        The run's number in the report.
    run : RunData
    entry : dict
        Its summary entry (with ``'opensees'``).
    out_dir : path
        Where the figures go.
    reference : seft_ros.analysis.reference.StructureReference, optional
        The run's reference with the recorded elements (default: computed).
    """
    info = entry['opensees']
    st = info['step_time']
    lines = [f'### Run {index}: the OpenSees model', '',
             f'Model {info["model"]}, {info["substeps"]} step(s) per sample'
             + (', stepped after the command (step: deferred)'
                if info.get('step') == 'deferred' else '')
             + f'. Step time over {st.get("steps", 0)} steps [ms]:', '',
             '| p50 | p99 | max | budget | over budget | over dt |', '|---|---|---|---|---|---|',
             f'| {_ms(st.get("p50_s"))} | {_ms(st.get("p99_s"))} | {_ms(st.get("max_s"))} | '
             f'{_ms(st.get("budget_s"))} | {st.get("over_budget", "–")} | '
             f'{st.get("over_period", "–")} |', '']
    pushover = pushover_lines(info.get('pushover'))
    if pushover:
        lines += [pushover[0] + (':' if len(pushover) > 1 else '.'), '']
        lines += [f'- {line.strip()}' for line in pushover[1:]]
        lines += [''] if len(pushover) > 1 else []
    from seft_ros.core.structure import test_setup
    setup = test_setup(run.params)
    tags = [int(e) for e in setup.structure.model.get('elements', ())]
    if tags:
        if reference is None:
            from seft_ros.opensees.reference import opensees_reference
            reference = opensees_reference(setup.substructures, float(run.params['dt']),
                                           run.ground_acceleration_m_s2, elements=tags)
        for tag in tags:
            png = hysteresis_figure(run, reference, tag,
                                    Path(out_dir) / f'hysteresis_run_{index}_ele{tag}.png',
                                    title=f'run {index}: element {tag}')
            lines += [f'![Run {index}: hysteresis of element {tag}]({png.name})', '']
    return lines
