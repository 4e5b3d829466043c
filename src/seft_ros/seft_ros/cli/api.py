"""The logic of the ``seft`` verbs as keyword-only functions (after ``ros2param/api``).

``run_experiments`` needs rclpy (it starts and watches the node graph); the others do not.
"""

import contextlib
from dataclasses import fields, replace
import json
import math
import os
from pathlib import Path
import random
import re
import time
from typing import Any, Callable

import numpy as np

from seft_msgs_py import parameters
from seft_msgs_py.domain import LOCK_DIR, claim_domain, held_by_ancestor
from seft_msgs_py.errors import InputError, Interrupted, ParameterError, SeftError
from seft_msgs_py.parameters import identification_run
from seft_msgs_py.sampling import single_blas_thread
from seft_msgs_py.stopping import signal_name
from seft_ros.analysis.bag import read_run
from seft_ros.analysis.rundata import RECORDING_CUT_SHORT, RunData
from seft_ros.cli import partition
from seft_ros.cli.config import (
    RIGS,
    expand_runs,
    layer_rigs,
    load_config,
    mapping_values,
    write_params_file,
)
from seft_ros.core import stability
from seft_ros.core.experiment import simulate
from seft_ros.core.ground_motion import (
    prepared_record,
    record_read,
    record_read_line,
    record_warnings,
)
from seft_ros.core.models import model_plugin
from seft_ros.core.predictors import MAX_BAND_ERROR
from seft_ros.core.reference_force import PREDICTORS
from seft_ros.core.structure import structure_of, test_setup

__all__ = ['NOTHING_RUN', 'interrupted_as', 'build_runs', 'output_dir', 'remove_empty_dirs',
           'run_experiments',
           'simulate_experiments', 'simulate_runs', 'compare_bags', 'find_bags',
           'summary_table', 'criteria_table',
           'Result', 'check_stability', 'check_domain', 'open_runner', 'stability_entry',
           'stability_report', 'stability_table', 'StabilityResult', 'identify_bags',
           'identification_table', 'check_ranges', 'RangeRefusedError', 'check_settings',
           'run_labels', 'alpha_text', 'predicted_error_warning', 'ACCURATE_TEST',
           'guard_check', 'played_record_s', 'predicted_error_text', 'MIN_PREDICTED_PLAY_S',
           'keep_previous']


class Result:
    """What a verb produced: the runs, the report directory and the summary entries."""

    def __init__(self, out_dir: Path, runs: list[RunData], summary: list[dict],
                 wall_time_s: float):
        self.out_dir = out_dir
        self.runs = runs
        self.summary = summary
        self.wall_time_s = wall_time_s


def build_runs(*, config: str | None = None, overrides: dict[str, Any] | None = None,
               alphas: list[float] | None = None,
               params_files: list[str] | None = None,
               progress: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """Parameter sets of the runs: defaults < config file < parameter files < overrides <
    alphas.

    Parameters
    ----------
    config : str, optional
        The configuration file.
    overrides : dict, optional
        Parameter values (the command line's options and ``--set``); None values are left
        out.
    alphas : list of float, optional
        ``--alpha``.
    params_files : list of str, optional
        ``--params`` files, layered over `config` (the first file's value of a parameter
        wins over a later file's). A file's ``rigs`` section (``seft identify``'s file of a
        structure's rigs) is merged into the configuration's rigs sections
        (:func:`~seft_ros.cli.config.layer_rigs`).
    progress : callable(str), optional
        Receives one ``settings:`` line per rig whose specimen is declared to yield, naming
        the settings chosen for it (:func:`~seft_ros.cli.config.expand_runs`).

    Raises
    ------
    InputError, ParameterError
        Bad configuration file or value; a ``rigs`` section of a parameter file without a
        structure to merge into, or for a rig the structure has not.
    """
    # the command line's values named as its own (before: as the configuration file's)
    for name, value in (overrides or {}).items():
        if value is not None and name not in parameters.MAPPING_PARAMETERS:
            for one in (value if isinstance(value, (list, tuple)) else [value]):
                try:
                    parameters.validate_value(name, one, where='command line')
                except ParameterError as exc:
                    if isinstance(one, str) and one.lower().endswith(('.yaml', '.yml')):
                        # (--predictor model lab.yaml: the file taken as a predictor)
                        raise ParameterError(
                            f'{exc} ({one} taken as its value: an option of several values '
                            'takes every word after it; give the configuration file '
                            'first)') from None
                    raise
    for one in alphas or ():
        parameters.validate_value('alpha', one, where='command line')
    values = load_config(config) if config else {}
    origin = dict.fromkeys(values, config)      # where each given value came from
    layered: dict[str, Any] = {}
    rig_layers = []
    replaced_by = None              # the --params file whose plant_model replaces config's
    for path in params_files or ():
        data = load_config(path, layer=True)
        sections = data.pop(RIGS, None)
        if sections:
            rig_layers.append((path, sections))
        for name, value in data.items():
            if name not in layered and value is not None:
                origin[name] = str(path)
            layered.setdefault(name, value)
        if 'plant_model' in data and values.get('plant_model') not in (None, '', 'none') \
                and replaced_by is None:
            replaced_by = path
    values.update({k: v for k, v in layered.items() if v is not None})
    values.update({k: v for k, v in (overrides or {}).items() if v is not None})
    origin.update({k: 'command line' for k, v in (overrides or {}).items() if v is not None})
    # a plant model or controller given by its file on the command line
    values = mapping_values(values, base=Path.cwd(), where='command line')
    for path, sections in reversed(rig_layers):      # the first file's values last: they win
        values = layer_rigs(values, sections, where=str(path))
    _refuse_overrides_no_rig_takes(values, overrides or {})
    for line in _file_values_no_rig_takes(values, origin) if progress is not None else ():
        progress(f'settings: {line}')
    if progress is not None:
        for line in _rigs_without_specimen(values, where=config or 'command line'):
            progress(f'settings: {line}')
    if alphas:
        values['alpha'] = list(alphas)
        origin['alpha'] = 'command line'
    notes = []
    where = config or 'command line'
    runs = expand_runs(values, where=where, notes=notes, origin=origin)
    if (replaced_by is not None and values.get('rig_model') == 'state_space'
            and values.get('rig_plant_model', 'none') in (None, '', 'none')):
        # a rig_model state_space without a rig_plant_model simulates its plant_model, which
        # its compensator and the guard read too: the file's (an identified model) replaces
        # the lab's for all three
        notes.append(f"--params {replaced_by}: its plant_model replaces {config}'s, and the "
                     'state_space rig simulates it: this run rehearses the design on the model '
                     "it was made from, not on the configuration's plant (without a "
                     'rig_plant_model one plant_model serves the rig, its compensator and the '
                     "guard; to rehearse the design on the configuration's plant, give that "
                     'plant as rig_plant_model there)')
    for note in notes if progress is not None else ():
        progress(f'settings: {note}')
    for line in _unstable_plant_models(runs) if progress is not None else ():
        progress(f'warning: {line}')
    for line in _servohydraulic_values_unused(values, runs) if progress is not None else ():
        progress(f'settings: {line}')
    if progress is not None and any(p.get('excitation_input') == 'valve_command'
                                    and not identification_run(p) for p in runs):
        # half of the open-loop identification run's two settings: the other is excitation
        progress('warning: excitation_input valve_command without an excitation (excitation '
                 'none) does nothing: these runs are closed-loop tests of the record; an '
                 'open-loop identification run also sets excitation (e.g. --set '
                 'excitation=noise)')
    # read every record now: a bad file is reported before anything starts
    seen = set()
    for p in runs:
        key = _record_key(p)
        if key not in seen:
            seen.add(key)
            info = record_read(p)                   # None: the default or an excitation
            if info is None:
                prepared_record(p)
            elif progress is not None:
                progress(record_read_line(info))
                for warning in record_warnings(info):
                    progress(f'warning: {warning}')
    return runs


#: seft's servohydraulic rig's parameters (``ServoHydraulicParams``) that a
#: ``state_space`` rig does not read: its plant model is the actuator; the six hydraulic
#: ones are read by ``force_controller: velocity_feedback`` alone. Measured (session 36):
#: each doubled, a ``state_space`` run with ``none``, ``model`` or ``adaptive`` and a
#: designed, loop_shaping or transfer_function controller, its range check and its guard
#: were bit for bit the same (a new user had set io_latency_s=0.01 there, silently).
#: seft's servohydraulic rig's parameters that no other rig and no controller reads; the
#: rest of :class:`~seft_plant_sim.servohydraulic.ServoHydraulicParams` (less the
#: accelerometer's range, every rig's) are its hydraulics, which ``velocity_feedback`` designs
#: with (:func:`_servohydraulic_values_unused`)
_SERVOHYDRAULIC_ONLY = ('io_latency_s', 'valve_time_constant_s', 'anti_alias_cutoff_hz')
_EVERY_RIGS = ('accelerometer_range_m_s2',)


def _servohydraulic_values_unused(values: dict[str, Any], runs: list[dict[str, Any]]
                                  ) -> list[str]:
    """One line naming the parameters of seft's servohydraulic rig that were given other
    than their defaults (in `values`: the configuration, ``--params``, the command line) for
    a run on the ``state_space`` rig, where they do nothing (``_SERVOHYDRAULIC_ONLY``; and
    its hydraulics but with ``velocity_feedback``); none otherwise."""
    if not runs or any(p.get('rig_model') != 'state_space' for p in runs):
        return []
    from seft_plant_sim.servohydraulic import ServoHydraulicParams
    unused = list(_SERVOHYDRAULIC_ONLY)
    if all(p.get('force_controller') != 'velocity_feedback' for p in runs):
        unused += [f.name for f in fields(ServoHydraulicParams)
                   if f.name not in _SERVOHYDRAULIC_ONLY + _EVERY_RIGS]
    defaults = parameters.defaults()        # (a full parameter file repeats them all)
    given = [f'{name}={values[name]!r}' for name in unused
             if values.get(name) is not None and values[name] != defaults.get(name)]
    if not given:
        return []
    return [f"{', '.join(given)}: seft's servohydraulic rig's, not read by the state_space "
            "rig, whose plant model (rig_plant_model, else plant_model) is the actuator and "
            'its delay: they do nothing in this run; put a delay or a valve into the plant '
            'model']


def _unstable_plant_models(runs: list[dict[str, Any]]) -> list[str]:
    """One line per plant model (``plant_model``, ``rig_plant_model``) of the runs' rigs
    with a pole outside the unit circle at ``dt``: a plant that diverges by itself, with no
    controller (a sign typo in a state matrix, a lab's model of another rig). Measured (a
    new user, 2026-12-01): ``a[2][2]`` of a valve-and-column model with its sign flipped was
    taken in silence, and its open-loop identification run ended at the force limit."""
    from seft_msgs_py.plant import parse_plant
    out, seen = [], set()
    for p in runs:
        if all(p.get(name, 'none') in (None, '', 'none')
               for name in ('plant_model', 'rig_plant_model')) \
                and 'plant_model' not in str(p.get('structure', '')):
            continue                       # no plant model in any rig (most runs)
        setup = test_setup(p)
        for rig in setup.rig_names:
            rp = setup.rig_params[rig]
            for name in ('plant_model', 'rig_plant_model'):
                text = rp.get(name, 'none')
                key = (rig, name, text, rp.get('dt'))
                if text in (None, '', 'none') or key in seen:
                    continue
                seen.add(key)
                try:
                    poles = parse_plant(text, dt=float(rp['dt']),
                                        where=f'parameter {name}').poles()
                except (SeftError, ValueError):
                    continue                   # the run says what does not parse
                worst = complex(poles[int(np.argmax(np.abs(poles)))]) if poles.size else 0j
                if abs(worst) <= 1.0 + 1e-9:
                    continue
                lam = np.log(worst) / float(rp['dt'])
                who = f'rig {rig}' if rig else 'the rig'
                out.append(f'parameter {name} of {who}: a pole outside the unit circle at '
                           f'dt (|z| {abs(worst):.6g}: grows at {lam.real:.4g} 1/s, '
                           f'{abs(lam.imag) / (2.0 * math.pi):.3g} Hz): the plant diverges by '
                           'itself, without a controller; check its signs (a state matrix '
                           'entry, a denominator coefficient)')
    return out


#: The specimen's parameters a structure's rig takes from its rigs section or the top level.
_SPECIMEN_KEYS = ('mass_kg', 'stiffness_N_per_m', 'damping_N_s_per_m')


def _rigs_without_specimen(values: dict[str, Any], *, where: str) -> list[str]:
    """One line per physical rig of a structure that declares no specimen: neither its
    ``rigs`` section (with the parameter files' merged in) nor the configuration's top level
    gives its mass, stiffness or damping, so the study's specimen is taken (the shipped
    ``two_story.yaml`` tests it so; a new user's structure with the section left out ran on
    it without a word, or was refused for a stiffness of 211000 N/m it never wrote)."""
    text = values.get('structure')
    if not isinstance(text, str) or not text.lstrip().startswith('{') \
            or any(k in values for k in _SPECIMEN_KEYS):
        return []
    doc = json.loads(text)
    sections = doc.get('rigs') or {}
    defaults = parameters.defaults()
    study = ', '.join(f'{k}={defaults[k]:g}' for k in _SPECIMEN_KEYS)
    return [f'{where}: rig {rig} (structure.physical.{dof}) declares no specimen in its '
            f"rigs.{rig} section: the study's is taken ({study})"
            for dof, rig in (doc.get('physical') or {}).items()
            if not any(k in (sections.get(rig) or {}) for k in _SPECIMEN_KEYS)]


def _same_value(a, b) -> bool:
    """Whether two parameter values are the same (a ``--set`` text and a number alike)."""
    try:
        return float(a) == float(b)
    except (TypeError, ValueError):
        return str(a) == str(b)


def _refuse_overrides_no_rig_takes(values: dict[str, Any], overrides: dict[str, Any]) -> None:
    """A command-line value (an option or ``--set``) that every rig of the structure sets
    otherwise in its own section changes nothing (a rig section beats a test-wide value):
    refused in one line. ``--rig state_space``, the documented rehearsal, ran a structure
    whose rigs set ``rig_model: actuator`` on those actuators, to the digit, and called it
    rehearsed.

    Raises
    ------
    InputError
        Such a value (the message names it, each rig's own value and the remedy).
    """
    from seft_ros.core.structure import Structure
    structure = values.get('structure', 'none')
    if structure in ('none', '', None):
        return
    try:
        sections = Structure.from_json(structure).rigs    # every rig, with its section
    except ParameterError:
        return                          # expand_runs names what is wrong with it
    rigs = sorted(sections)
    for name, value in overrides.items():
        if value is None or not rigs or not all(name in sections[r] for r in rigs):
            continue
        if all(_same_value(sections[r][name], value) for r in rigs):
            continue
        own = ', '.join(f'{r}: {sections[r][name]}' for r in rigs)
        raise InputError(f'command line: {name}={value}: no rig of the structure takes it, '
                         f'every rig section sets its own ({own}) and a rig section beats a '
                         "test-wide value; set it in the rigs' sections (or a --params file's "
                         'rigs section)')


def _file_values_no_rig_takes(values: dict[str, Any], origin: dict[str, str]) -> list[str]:
    """One line per test-wide value of a file (the configuration, a ``--params`` file) that
    every rig of the structure sets otherwise in its own section: it changes nothing (a rig
    section beats a test-wide value). The command line's are refused
    (:func:`_refuse_overrides_no_rig_takes`); a file's were taken in silence (a new user's
    top-level force_controller and stiffness_N_per_m, runs bit for bit the same; session 36).
    ``mass_kg`` is not: the test-wide one scales the record to ``amplitude_N``."""
    from seft_ros.core.structure import Structure
    structure = values.get('structure', 'none')
    if structure in ('none', '', None):
        return []
    try:
        sections = Structure.from_json(structure).rigs
    except ParameterError:
        return []
    rigs = sorted(sections)
    out = []
    for name, source in origin.items():
        value = values.get(name)
        if (source == 'command line' or value is None or not rigs or name == 'mass_kg'
                or not all(name in sections[r] for r in rigs)
                or all(_same_value(sections[r][name], value) for r in rigs)):
            continue
        own = ', '.join(f'{r}: {sections[r][name]}' for r in rigs)
        out.append(f'{source}: {name}={value}: does nothing, every rig section sets its own '
                   f"({own}) and a rig section beats a test-wide value; set it in the rigs' "
                   'sections')
    return out


def output_dir(*, out: str | None, name: str, created: list[Path] | None = None) -> Path:
    """The output directory: `out` (must be new or empty) or ``runs/<name>[-N]``.

    Parameters
    ----------
    out : str or None
        ``--out``; None for ``runs/<name>``, with ``-2``, ``-3``, ... if that exists.
    name : str
        Name of the default directory.
    created : list of Path, optional
        The directories this call makes (the output directory and any missing parent) are
        appended to it, outermost first, for :func:`remove_empty_dirs` on a failure.

    Returns
    -------
    Path
        The directory, which exists and is empty.

    Raises
    ------
    InputError
        `out` exists and is not an empty directory, or the directory cannot be made.
    """
    if out:
        path = Path(out)
        if path.exists() and (not path.is_dir() or any(path.iterdir())):
            raise InputError(f'{path}: output directory exists and is not empty; expected a '
                             'new directory')
    else:
        base = Path('runs') / name
        path, i = base, 1
        while path.exists():
            i += 1
            path = base.with_name(f'{base.name}-{i}')
    missing = [d for d in (*reversed(path.parents), path) if not d.exists()]
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        what = f'--out {out}' if out else str(path)
        raise InputError(f'{what}: cannot create the output directory '
                         f'({exc.strerror or exc}); expected a directory that can be '
                         'made') from None
    if created is not None:
        created.extend(missing)
    return path


def remove_empty_dirs(dirs: list[Path]) -> None:
    """Remove the directories of `dirs` that hold no file (innermost first), so that a
    command that failed leaves nothing behind; a directory with a file in it (a node's log,
    a bag of a run that was stopped) stays."""
    for d in reversed(dirs):
        if d.is_dir() and not any(f.is_file() or f.is_symlink() for f in d.rglob('*')):
            for sub in sorted(d.rglob('*'), key=lambda q: len(q.parts), reverse=True):
                sub.rmdir()
            d.rmdir()


def alpha_text(alpha: float) -> str:
    """`alpha` as a run label shows it: ``:g`` (``0.5``, ``1``), or every digit when ``:g``
    would round it (``0.1234561``), so that different alphas never share a label."""
    short = f'{float(alpha):g}'
    return short if float(short) == float(alpha) else repr(float(alpha))


def _record_names(records: list) -> dict:
    """Each record's part of a run label: its file stem; records that share a stem are told
    apart by their folder's name before it (``rec2_dt001``), and where that is shared too, by
    their position among them (``dt001-2``)."""
    def clean(text):
        return ''.join(c if c.isalnum() or c in '-_.' else '_' for c in text)

    names = {r: clean(Path(str(r)).stem) for r in records}
    for rule in ('folder', 'index'):
        groups: dict[str, list] = {}
        for r in records:
            groups.setdefault(names[r], []).append(r)
        for shared in (g for g in groups.values() if len(g) > 1):
            for i, r in enumerate(shared, 1):
                stem = clean(Path(str(r)).stem)
                names[r] = (f'{clean(Path(str(r)).resolve().parent.name)}_{stem}'
                            if rule == 'folder' else f'{stem}-{i}')
    return names


def run_labels(runs: list[dict]) -> list[str]:
    """The runs' directory names, unique (each run's ``_run_label``).

    Raises
    ------
    InputError
        Two runs still share a label (the same run twice: refused before anything starts).
    """
    records = list(dict.fromkeys(str(r['record']) for r in runs))
    several_alphas = len({float(r.get('alpha', 0.0)) for r in runs}) > 1
    names = _record_names(records) if len(records) > 1 else {}
    labels = []
    for p in runs:
        if has_structure(p):
            label = 'structure_' + (f'alpha_{alpha_text(p["alpha"])}_' if several_alphas
                                    else '') + str(p['predictor'])
        else:
            label = f'alpha_{alpha_text(p["alpha"])}_{p["rig_model"]}_{p["predictor"]}'
        if names:
            label += '_' + names[str(p['record'])]
        labels.append(label)
    shared = sorted({lb for lb in labels if labels.count(lb) > 1})
    if shared:
        raise InputError(f'runs {", ".join(shared)}: the same run twice; expected each record, '
                         'predictor and alpha once')
    return labels


def _run_label(p: dict, runs: list[dict] | None = None) -> str:
    """A run's directory name (``alpha_<alpha>_<rig>_<predictor>``, a structure test's
    ``structure_<predictor>``, with ``alpha_<alpha>_`` before the predictor when the runs
    have several alphas); with several records in `runs`, the record's part too
    (:func:`_record_names`). Alpha as :func:`alpha_text` writes it."""
    runs = runs or [p]
    index = next((i for i, r in enumerate(runs) if r is p), None)
    if index is None:
        return run_labels([p])[0]
    return run_labels(runs)[index]


def _record_key(p: dict) -> tuple:
    """The parameters that decide a run's prepared record (runs that share them read and
    prepare it once)."""
    return tuple(p.get(k) for k in ('record', 'dt', 'mass_kg', 'amplitude_N', 'scale_factor',
                                    'time_scale', 'record_resampling', 'duration_s',
                                    'n_steps'))


def _note_records_read(data: list[RunData], runs: list[dict]) -> None:
    """Put what each run read from its record file (:func:`record_read`, once per record
    and preparation) in ``rd.extra['record_read']`` for ``summary.json`` and the report.
    Records of one file stem in other folders are named as their runs' labels name them
    (``rd.record_name``: ``rec2_dt001``, :func:`_record_names`), so that the tables, the
    summary and the report tell their runs apart."""
    read: dict[tuple, dict | None] = {}
    records = list(dict.fromkeys(str(p['record']) for p in runs))
    stems = [Path(r).stem for r in records]
    names = _record_names(records) if len(set(stems)) < len(stems) else {}
    for rd, p in zip(data, runs):
        key = _record_key(p)
        if key not in read:
            read[key] = record_read(p)
        if read[key] is not None:
            rd.extra['record_read'] = read[key]
        record = str(p['record'])
        if names and stems.count(Path(record).stem) > 1:
            rd.record_name = names[record]


def _finish(out_dir: Path, runs: list[RunData], title: str, t0: float,
            not_compared: tuple[str, ...] = ()) -> Result:
    from seft_ros.analysis.report import write_report  # matplotlib: only for the report
    paths = write_report(runs, out_dir, title=title, not_compared=not_compared)
    summary = json.loads(Path(paths.summary_json).read_text())['runs']
    return Result(out_dir, runs, summary, time.monotonic() - t0)


def simulate_experiments(*, runs: list[dict], out_dir: Path,
                         progress: Callable[[str], None] = print, title: str = '',
                         force: bool = False, workers: int | None = None,
                         bag: bool = False, strict: bool = False) -> Result:
    """Run each parameter set with :func:`~seft_ros.core.experiment.simulate` (no ROS) and
    write the report.

    Before the first run, :func:`check_stability` (`force`: warn instead of refusing) and
    :func:`check_ranges` (`strict`: refuse instead of warning). One run is simulated in this
    process; several run in a pool of worker processes
    (:class:`concurrent.futures.ProcessPoolExecutor`), each run in one worker, so the
    numbers are those of each run alone. Progress lines: ``[label] step k/n`` about every
    0.5 s of a run, and one line per finished run, in the order the runs finish.

    Parameters
    ----------
    runs : list of dict
        Resolved parameter sets (:func:`build_runs`).
    out_dir : Path
        Report directory; one sub-directory per run with its ``params.yaml``.
    progress : callable(str)
        Receives the progress lines (called in this process only).
    title : str
        Report title.
    force : bool
        Run predicted-unstable runs anyway (with a warning).
    strict : bool
        Refuse the runs when a rig's reference peak exceeds a sensor range or the actuator's
        capacity (``--strict``; default: one warning line per channel).
    workers : int >= 1, optional
        Worker processes (default ``os.cpu_count()``; never more than the runs). 1: every
        run in this process, one after the other.
    bag : bool
        Also write each run's bag to ``out_dir/<run>/bag``, the bag the node graph records
        (:func:`seft_ros.analysis.bagwrite.write_run_bag`), for ``seft compare`` and
        ``seft identify``.

    Returns
    -------
    Result
        The runs in the order of `runs`.

    Raises
    ------
    InputError, ParameterError
        Bad record or parameter.
    PredictedUnstableError
        A run is predicted unstable and `force` is False.
    RangeRefusedError
        `strict` and a run's reference exceeds a range or capacity.
    KeyboardInterrupt
        Ctrl-C: the runs not started are cancelled, the running ones stop at their next
        progress check (within about 0.5 s) and the workers exit before this re-raises.
    """
    t0 = time.monotonic()
    labels = run_labels(runs)             # each run its own directory, before anything starts
    bags = [out_dir / label / 'bag' for label in labels] if bag else []
    for path in bags:
        if path.exists():
            raise InputError(f'{path}: the bag exists already; expected a new --out directory')
    # the settings lines first: they may say why the guard refuses (a new user's specimen
    # 1000 times too soft, refused with its cause said only under --force; session 38)
    check_settings(runs=runs, progress=progress)
    checks = check_stability(runs=runs, force=force, progress=progress)
    ranges = check_ranges(runs=runs, strict=strict, progress=progress)
    data = simulate_runs(runs=runs, out_dir=out_dir, progress=progress, workers=workers)
    for rd, check, limits in zip(data, checks, ranges):
        rd.extra['stability'] = stability_entry(check)
        rd.extra['range_check'] = limits.as_dict()
    _note_records_read(data, runs)
    if bags:
        from seft_ros.analysis.bagwrite import write_run_bag
        for rd, path in zip(data, bags):
            write_run_bag(rd, path)
            progress(f'bag: {path}')
    return _finish(out_dir, data, title or 'seft simulate', t0)


def simulate_runs(*, runs: list[dict], out_dir: Path,
                  progress: Callable[[str], None] = print,
                  workers: int | None = None) -> list[RunData]:
    """The runs of :func:`simulate_experiments` without the guard and the report.

    Parameters and progress lines as :func:`simulate_experiments`; writes each run's
    ``params.yaml`` under `out_dir`.

    Returns
    -------
    list of RunData
        In the order of `runs`.

    Raises
    ------
    InputError, ParameterError
        Bad record or parameter.
    KeyboardInterrupt
        As :func:`simulate_experiments`.
    """
    labels = run_labels(runs)
    n_workers = min(len(runs), workers or os.cpu_count() or 1)
    if n_workers > 1:
        return _simulate_pool(runs, labels, out_dir, progress, n_workers)
    data = []
    for p, label in zip(runs, labels):
        progress(f'[{label}] simulating')
        rd = simulate_any(p, progress=lambda k, n, lb=label: progress(f'[{lb}] step {k}/{n}'))
        data.append(_run_finished(p, rd, label, out_dir, progress))
    return data


def has_structure(params) -> bool:
    """Whether a run is a structure test (parameter ``structure``)."""
    return params.get('structure', 'none') not in ('none', '', None)


def simulate_any(params: dict, progress=None):
    """One run in one process: :func:`~seft_ros.core.experiment.simulate`."""
    return simulate(params, progress=progress)


def _run_finished(params: dict, rd: RunData, label: str, out_dir: Path,
                  progress: Callable[[str], None], note: str = '') -> RunData:
    """Write the run's ``params.yaml`` and report its outcome; return `rd`."""
    run_dir = out_dir / label
    run_dir.mkdir(parents=True, exist_ok=True)
    write_params_file(params, run_dir / 'params.yaml')
    for warning in rd.extra.get('warnings') or ():
        progress(f'[{label}] warning: {warning}')
    state = 'stable' if rd.stable else 'ABORTED: ' + str(rd.abort_reason)
    progress(f'[{label}] {state}{note}')
    return rd


class _Stopped(Exception):
    """Raised in a worker's run when the parent asked the pool to stop (Ctrl-C)."""


#: A worker process's queue of progress lines to the parent and its stop flag (set by
#: :func:`_worker_init`; None in the parent).
_WORKER = None


def _worker_init(lines, stop) -> None:
    """Pool worker start-up: Ctrl-C is the parent's to handle; keep the queue and the flag.

    A worker does not wait at exit until the parent has read its progress lines (after
    Ctrl-C nobody does): the lines may be lost, the worker never hangs.
    """
    import signal
    global _WORKER
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    lines.cancel_join_thread()
    _WORKER = (lines, stop)


def _simulate_in_worker(index: int, params: dict, label: str) -> tuple[int, RunData]:
    """One run in a pool worker; its progress goes to the parent through the queue."""
    lines, stop = _WORKER

    def report(k, n):
        if stop.is_set():
            raise _Stopped()
        lines.put(f'[{label}] step {k}/{n}')

    lines.put(f'[{label}] simulating')
    return index, simulate_any(params, progress=report)


def _simulate_pool(runs: list[dict], labels: list[str], out_dir: Path,
                   progress: Callable[[str], None], n_workers: int) -> list[RunData]:
    """The runs in a process pool; results in the order of `runs`."""
    # fork: the workers start at once with everything imported (no second import of numpy,
    # scipy and the record). BLAS stays at one thread in this process while the pool runs:
    # forked so, a worker never starts BLAS threads, and none spin here (idle BLAS threads
    # spin and took the workers' cores: 8 short runs on 2 workers 0.47 s instead of 0.3 s)
    with single_blas_thread():
        return _run_pool(runs, labels, out_dir, progress, n_workers)


def _run_pool(runs, labels, out_dir, progress, n_workers):
    import concurrent.futures as cf
    import multiprocessing
    import queue

    ctx = multiprocessing.get_context('fork')
    lines, stop = ctx.Queue(), ctx.Event()
    results: list[RunData | None] = [None] * len(runs)
    progress(f'{len(runs)} runs on {n_workers} worker processes')
    pool = cf.ProcessPoolExecutor(n_workers, mp_context=ctx, initializer=_worker_init,
                                  initargs=(lines, stop))

    def drain():
        while True:
            try:
                progress(lines.get_nowait())
            except queue.Empty:
                return

    try:
        index = {pool.submit(_simulate_in_worker, i, p, lb): i
                 for i, (p, lb) in enumerate(zip(runs, labels))}
        pending = set(index)
        finished = 0
        while pending:
            done, pending = cf.wait(pending, timeout=0.2, return_when=cf.FIRST_COMPLETED)
            drain()
            for fut in sorted(done, key=index.get):
                _, rd = fut.result()          # a failed run raises here: the rest stops
                i = index[fut]
                finished += 1
                results[i] = _run_finished(runs[i], rd, labels[i], out_dir, progress,
                                           f' ({finished}/{len(runs)} runs done)')
    except BaseException:
        stop.set()                            # running runs stop at their next progress check
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    finally:
        pool.shutdown(wait=True)
        lines.close()
    return results


#: The domains ``seft run`` claims from when none is given (tests use 200-232).
RUN_DOMAINS = range(100, 200)


class _InheritedClaim:
    """The domain claim of an ancestor process (``seft_msgs_py.domain``): nothing to
    release."""

    def close(self) -> None:
        """Nothing: the ancestor holds the claim."""


#: The largest ROS domain id (Fast DDS's port mapping; REP 2005 / the ROS 2 domain-id docs).
MAX_DOMAIN_ID = 232


def _checked_domain(value, source: str) -> int:
    """`value` as a ROS domain id, or InputError naming `source` (one line)."""
    try:
        domain = int(value)
    except (TypeError, ValueError):
        domain = -1
    if str(value).strip() != str(domain) or not 0 <= domain <= MAX_DOMAIN_ID:
        raise InputError(f'{source}={value!r}: expected an integer 0-{MAX_DOMAIN_ID}')
    return domain


def check_domain(domain_id: int | None = None) -> None:
    """Check `domain_id` (``--domain-id``) and ``ROS_DOMAIN_ID``, if set.

    Raises
    ------
    InputError
        Either is not an integer 0-232 (the message names which).
    """
    if domain_id is not None:
        _checked_domain(domain_id, '--domain-id')
    if os.environ.get('ROS_DOMAIN_ID'):
        _checked_domain(os.environ['ROS_DOMAIN_ID'], 'ROS_DOMAIN_ID')


def _domain_id() -> int:
    env = os.environ.get('ROS_DOMAIN_ID')
    if env:
        return _checked_domain(env, 'ROS_DOMAIN_ID')
    return random.SystemRandom().randint(100, 199)


def check_nodes(nodes: list[str], runs: list[dict]) -> list[str]:
    """Validate ``seft run --nodes``: names of the graph of every run, none twice.

    Returns
    -------
    list of str
        The names, in the graph's start order.

    Raises
    ------
    InputError
        A name that is no node of a run's graph (the message lists the valid ones).
    """
    from seft_msgs_py.graph import Graph
    if not nodes:
        raise InputError('--nodes: expected one or more node names')
    for p in runs:
        graph = ['recorder', *Graph.from_parameters(p).nodes()]
        what = (f'the {p["rig_model"]!r} rig\'s graph' if not has_structure(p)
                else "the structure's graph")
        for name in nodes:
            if name not in graph:
                raise InputError(f'--nodes {name}: not a node of {what}; expected some of '
                                 f'{", ".join(graph)}')
    if len(set(nodes)) != len(nodes):
        raise InputError(f'--nodes {",".join(nodes)}: a node is named twice')
    return list(nodes)


def _shared_domain(domain_id: int | None) -> int:
    """The ROS domain of a run over several hosts: given, never chosen at random."""
    if domain_id is not None:
        return _checked_domain(domain_id, '--domain-id')
    if not os.environ.get('ROS_DOMAIN_ID'):
        raise InputError('--nodes: the hosts of a run must share its ROS domain; set '
                         'ROS_DOMAIN_ID (or --domain-id) to the same value on every host')
    return _domain_id()


def _read_outcome(outcome, label: str, progress: Callable[[str], None]) -> RunData:
    """Read a graph run's bag back and say how the run went.

    Raises
    ------
    SeftError
        The bag holds no step: the rig's reason when it ended before its first sample (a UDP
        bridge's controller not found, or refusing the run), else the bag's."""
    try:
        rd = read_run(outcome.bag_path)
    except SeftError:
        if outcome.rig_state in ('failed', 'aborted') and outcome.message:
            # the rig ended before its first sample: its reason, not the empty bag's
            raise SeftError(f'[{label}] the rig {outcome.rig_state} before its first sample: '
                            f'{outcome.message}; nothing was run') from None
        raise
    # a warning the bag holds and the console did not say: its report reached the recorder
    # but reached the runner only after the recorder closed the bag (no order between two
    # nodes' reports; a reliable resend waits for the writer's next heartbeat)
    said = set(outcome.warnings_said)
    for st in rd.extra.get('node_statuses', []):
        key = (st.get('name', '?'), st.get('warning'))
        if key[1] and key not in said:
            said.add(key)
            progress(f'[{label}] {key[0]}: warning: {key[1]} (from the bag: not said during '
                     'the run)')
    ended = 'RECORDING CUT SHORT' if rd.recording_cut_short else 'ABORTED'
    state = 'stable' if rd.stable else f'{ended} at {rd.unstable_at_s:.3f} s: ' \
        f'{rd.abort_reason}' + _watchdog_hint(rd.params.get('mode'), rd.abort_reason)
    stepping = rd.extra.get('wall_s')          # the rigs' stepping, without the start-up
    stepped = f' (stepping {stepping:.1f} s)' if stepping else ''
    progress(f'[{label}] {rd.n_steps} steps in {outcome.wall_time_s:.1f} s wall{stepped}; '
             f'{state}; bag {outcome.bag_path}')
    from seft_ros.analysis.findings import bridge_entry, bridge_lines
    for kind, line in bridge_lines(bridge_entry(rd)):
        # a rig behind the UDP bridge: its link's counts, and what was not right with it
        progress(f'[{label}] ' + ('' if kind == 'counts' else 'WARNING: ') + line)
    _replay_if_due(rd, label, progress)
    return rd


def _replay_if_due(rd: RunData, label: str, progress: Callable[[str], None]) -> None:
    """A real-time run of seft's simulated rigs that erred with late steps: replay its
    timing (:func:`~seft_ros.analysis.timing_replay.replay_due`), say what they cost and keep it
    for the summary and the report (its flag: the host's timing)."""
    from seft_ros.analysis.findings import timing_replay_line
    from seft_ros.analysis.metrics import compare_run, summary_entry
    from seft_ros.analysis.timing_replay import replay_due, replay_timing
    worst: dict = {}

    def worst_nrms() -> dict:
        worst.update(summary_entry(rd, compare_run(rd)).get('worst_nrms') or {})
        return worst

    try:
        if not replay_due(rd, worst_nrms):
            return
        why = 'an error above 1 %' if rd.stable else 'an abort'
        progress(f'[{label}] late steps and {why}: replaying the run in process, as it ran '
                 'and in time')
        rd.extra['timing_replay'] = replay = replay_timing(rd, recorded=worst or None)
    except SeftError as exc:
        progress(f'[{label}] no timing replay: {exc}')
        return
    if replay:
        progress(f'[{label}] timing: {timing_replay_line(replay)}')


def _run_here(runs, out_dir, progress, domain, nodes, processes, live) -> Result | None:
    """Run this host's `nodes` of every run (the others run on other hosts); the report
    where the recorder runs (None elsewhere)."""
    from seft_ros.cli.runner import GraphRunner  # rclpy only for this verb
    t0 = time.monotonic()
    with interrupted_as(lambda exc: NOTHING_RUN):
        runner = GraphRunner(domain, progress, localhost_default=False, processes=processes)
    viewer = None
    data = []
    now: list[str] = []           # the run in progress
    ran: list[str] = []           # the runs over
    try:
        with interrupted_as(lambda exc: _runs_interrupted(exc, out_dir, now, ran)):
            viewer = _start_live(live, runner, out_dir, progress)
            present = runner.present_nodes(nodes)
            if present:
                raise SeftError(f'ROS_DOMAIN_ID={domain} already has node(s) '
                                f'{", ".join(present)}: another run? Stop it or choose another '
                                'domain on every host')
            for p, label in zip(runs, run_labels(runs)):
                now[:] = [label]
                outcome = runner.run(p, out_dir / label, label=f'[{label}] ', nodes=nodes)
                ran.append(now.pop())
                if outcome.recorded_here:
                    data.append(_read_outcome(outcome, label, progress))
                else:
                    progress(f'[{label}] run over on this host ({", ".join(nodes)}): rig '
                             f'{outcome.rig_state or "not heard"}'
                             + (f': {outcome.message}' if outcome.message else '')
                             + f'; outcome in {outcome.run_dir / "outcome.json"}')
    finally:
        if viewer is not None:
            viewer.close()
        runner.close()
    if 'recorder' not in nodes:
        return None
    with interrupted_as(lambda exc: _runs_interrupted(exc, out_dir, now, ran)):
        return _finish(out_dir, data, 'seft run (several hosts)', t0)


def open_runner(*, domain_id: int | None = None, progress: Callable[[str], None] = print,
                checks: Callable[[], None] = lambda: None, processes: str = 'node'):
    """A :class:`~seft_ros.cli.runner.GraphRunner` in a ROS domain of its own: claimed on this
    machine (``seft_msgs_py.domain``) and carrying no seft topics (nodes started by hand).

    `domain_id` (else ``ROS_DOMAIN_ID``, else a free one of ``RUN_DOMAINS``); `checks` runs
    once while discovery settles (the pre-run checks); `processes`: how the runner starts
    the nodes (``seft_ros.cli.partition.PROCESSES``). Returns ``(runner, claim)``; close
    both when done.

    Raises
    ------
    SeftError
        The domain chosen is claimed or busy, or no free domain was found.
    """
    from seft_ros.cli.runner import GraphRunner, discovery_settle_s  # rclpy for this verb

    settle = discovery_settle_s()
    chosen = _checked_domain(domain_id, '--domain-id') if domain_id is not None else (
        _domain_id() if os.environ.get('ROS_DOMAIN_ID') else None)
    # claim the domain (seft_msgs_py.domain: no two seft processes of this machine meet),
    # then check that nothing else (nodes started by hand) publishes seft topics there
    claim, checked = None, False
    for _ in range(5):
        if claim is not None:
            claim.close()
        try:
            if chosen is None:
                domain, claim = claim_domain(RUN_DOMAINS,
                                             start=random.SystemRandom().randrange(100))
            elif held_by_ancestor(chosen):       # e.g. a test session's run: its claim
                domain, claim = chosen, _InheritedClaim()
            else:
                domain, claim = claim_domain([chosen])
        except RuntimeError:
            if chosen is not None:
                raise SeftError(f'ROS_DOMAIN_ID={chosen} is claimed by another seft process '
                                f'on this machine (lock {LOCK_DIR}/{chosen}.lock): choose '
                                'another --domain-id') from None
            raise SeftError(f'no free ROS domain in {RUN_DOMAINS[0]}-{RUN_DOMAINS[-1]}: every '
                            f'one is claimed (lock files in {LOCK_DIR})') from None
        runner = GraphRunner(domain, progress, processes=processes)
        joined = time.monotonic()
        if not checked:
            # the pre-run checks while discovery settles in the background (DDS threads):
            # the busy-topic wait below is then what is left of DISCOVERY_SETTLE_S
            try:
                checks()
            except BaseException:
                runner.close()
                claim.close()
                raise
            checked = True
        busy = runner.busy_topics(max(0.0, settle - (time.monotonic() - joined)))
        if not busy:
            break
        runner.close()
        if chosen is not None:
            claim.close()
            raise SeftError(f'ROS_DOMAIN_ID={chosen} already carries seft topics '
                            f'({", ".join(busy)}): another run? Choose another --domain-id')
    else:
        claim.close()
        raise SeftError('no free ROS domain found for the run (5 random tries)')
    return runner, claim


def _start_live(live, runner, out_dir: Path, progress: Callable[[str], None]):
    """The live view of ``seft run --live`` in the runner's domain (None without)."""
    if live is None:
        return None
    from seft_ros.cli.live import start_live
    viewer = start_live(live, runner.env, out_dir, progress)
    # the rig waits for a view that listens (one that went off would only delay the start)
    runner.live_view = viewer is not None and viewer.ready.is_set() and viewer.proc.poll() is None
    return viewer


def run_experiments(*, runs: list[dict], out_dir: Path,
                    progress: Callable[[str], None] = print, title: str = '',
                    domain_id: int | None = None, force: bool = False,
                    nodes: list[str] | None = None, processes: str = 'node',
                    live=None, strict: bool = False) -> Result | None:
    """Run each parameter set as a node graph (separate processes over DDS), record a bag
    per run, read the bags back and write the report.

    `processes` (``seft run --processes``): ``node``, one process per node; ``loop``, the
    nodes of each rig's loop in one process (``seft_ros.cli.partition.PROCESSES``).

    `live` (``seft run --live``, a :class:`~seft_ros.live.access.LiveOptions`): the live
    view of the runs (:mod:`seft_ros.cli.live`), in the run's domain for every run.

    Before any node starts, :func:`check_stability` (`force`: warn instead of refusing) and
    :func:`check_ranges` (`strict`: refuse instead of warning; `force`: run a real-time run
    beyond its actuator's capacity, with its warning).

    `nodes` (``seft run --nodes``): start only these nodes; the rest of the graph runs on
    other hosts in the same ROS domain (``ROS_DOMAIN_ID`` or `domain_id`, required then;
    discovery range and static peers from the environment). Returns None on a host without
    the recorder (the bag and the report are on the recorder's host).

    Raises
    ------
    PredictedUnstableError
        A run is predicted unstable and `force` is False (nothing started).
    RangeRefusedError
        `strict` and a run's reference exceeds a range or capacity, or a real-time run's
        exceeds its actuator's capacity and not `force` (nothing started).
    InputError
        `nodes` names no node of the graph, several hosts without a shared domain, or
        `processes` is not one of ``node``, ``loop``.
    SeftError
        A node failed, died, was stopped or the graph stalled (message names the node, when,
        and its log).
    Interrupted
        Ctrl-C, SIGTERM or SIGHUP (a ``KeyboardInterrupt``), with what was reached: nothing
        run; the run in progress ended (its rig's safe state, its bag) and the runs before
        it, no report written; or every run, and the report not written.
    """
    if processes not in partition.PROCESSES:
        raise InputError(f'--processes {processes}: expected '
                         f'{" or ".join(partition.PROCESSES)}')
    with interrupted_as(lambda exc: NOTHING_RUN):
        run_labels(runs)                  # each run its own directory, before anything starts
        if nodes is not None:
            nodes = check_nodes(nodes, runs)
            check_settings(runs=runs, progress=progress)
            check_stability(runs=runs, force=force, progress=progress)
            check_ranges(runs=runs, strict=strict, force=force, progress=progress)
    if nodes is not None:
        return _run_here(runs, out_dir, progress, _shared_domain(domain_id), nodes, processes,
                         live)
    t0 = time.monotonic()

    predicted, ranges = [], []

    def checks():
        check_settings(runs=runs, progress=progress)     # first: they may say why (above)
        predicted.extend(check_stability(runs=runs, force=force, progress=progress))
        ranges.extend(check_ranges(runs=runs, strict=strict, force=force,
                                   progress=progress))
    with interrupted_as(lambda exc: NOTHING_RUN):
        runner, claim = open_runner(domain_id=domain_id, progress=progress, checks=checks,
                                    processes=processes)
    data = []
    viewer = None
    now: list[str] = []           # the run in progress
    ran: list[str] = []           # the runs over
    with interrupted_as(lambda exc: _runs_interrupted(exc, out_dir, now, ran)):
        try:
            viewer = _start_live(live, runner, out_dir, progress)
            for p, label in zip(runs, run_labels(runs)):
                now[:] = [label]
                outcome = runner.run(p, out_dir / label, label=f'[{label}] ')
                ran.append(now.pop())
                data.append(_read_outcome(outcome, label, progress))
        finally:
            if viewer is not None:
                viewer.close()
            runner.close()
            claim.close()
    with interrupted_as(lambda exc: _runs_interrupted(exc, out_dir, now, ran)):
        for rd, check, limits in zip(data, predicted, ranges):
            rd.extra['stability'] = stability_entry(check)
            rd.extra['range_check'] = limits.as_dict()
        _note_records_read(data, runs)
        return _finish(out_dir, data, title or 'seft run', t0)


#: What an interrupted ``seft run`` reached before any node started.
NOTHING_RUN = 'before any node started: nothing was run'


@contextlib.contextmanager
def interrupted_as(state: Callable[[KeyboardInterrupt], str]):
    """Raise a ``KeyboardInterrupt`` of the block as :class:`~seft_msgs_py.errors.Interrupted`
    with ``state(exc)``: what the command had reached (``seft``'s last line).

    Raises
    ------
    Interrupted
        In place of a ``KeyboardInterrupt`` of the block (Ctrl-C, SIGTERM, SIGHUP).
    """
    try:
        yield
    except KeyboardInterrupt as exc:
        raise Interrupted(signal_name(exc), state(exc)) from None


def _runs_interrupted(exc: KeyboardInterrupt, out_dir: Path, now: list[str],
                      ran: list[str]) -> str:
    """What ``seft run`` reached when interrupted: the run in progress `now` (as the runner
    ended it, :meth:`~seft_ros.cli.runner.GraphRunner.run`), the runs over (`ran`), and
    that no report was written (``seft compare`` writes one from the bags)."""
    if now:
        ended = (exc.state if isinstance(exc, Interrupted) else
                 'left at once while the run ended; its nodes stop the run by themselves '
                 '(their logs say how)')
        if not ran and isinstance(exc, Interrupted) and exc.state.startswith('before'):
            return NOTHING_RUN
        parts = [f'[{now[0]}] {ended}']
        if ran:
            parts.append(f'{len(ran)} earlier run(s) complete')
    elif ran:
        parts = [f'{len(ran)} run(s) complete, their bags in {out_dir}']
    else:
        return NOTHING_RUN
    if any(out_dir.glob('*/bag')):
        parts.append(f'no report written: `seft compare {out_dir}` writes one from the '
                     'bag(s) kept')
    return '; '.join(parts)


def _natural_key(path: Path) -> list:
    """Sort key that orders numbers by value: alpha_0 < alpha_0.5 < alpha_1 < alpha_10."""
    parts = re.split(r'(\d+(?:\.\d+)?)', path.name)
    return [(0, float(p), '') if i % 2 else (1, 0.0, p) for i, p in enumerate(parts)]


def _is_bag(p: Path) -> bool:
    """Whether `p` is a bag directory (``metadata.yaml`` or a storage file in it)."""
    return p.is_dir() and ((p / 'metadata.yaml').is_file()
                           or any(p.glob('*.mcap')) or any(p.glob('*.db3')))


def find_bags(paths: list[str]) -> list[Path]:
    """The bags named by `paths`: bags, run directories or folders of run directories.

    Parameters
    ----------
    paths : list of str
        Each one a bag (a directory with ``metadata.yaml`` or a ``.mcap``/``.db3`` file), a
        run directory of ``seft run`` (holding ``bag/``) or a folder of run directories
        (``seft run --out DIR``: ``DIR/<run>/bag``, taken in natural order of the run names,
        numbers by value; :func:`compare_bags` then numbers them as the folder's
        ``summary.json`` does).

    Returns
    -------
    list of Path
        The bags, in the order of `paths`.

    Raises
    ------
    InputError
        A path does not exist, or is none of the three (a ``seft simulate`` directory holds
        no bag: its report is already written).
    """
    is_bag = _is_bag
    out: list[Path] = []
    for text in paths:
        path = Path(text)
        if not path.exists():
            raise InputError(f'{path}: no such bag or run directory')
        if is_bag(path) or path.is_file():
            out.append(path)  # a file: read_run says what is wrong with it
        elif is_bag(path / 'bag'):
            out.append(path / 'bag')
        else:
            runs = sorted((d for d in path.iterdir() if is_bag(d / 'bag')), key=_natural_key)
            if not runs:
                raise InputError(
                    f'{path}: not a bag, a run directory (with bag/) or a folder of run '
                    'directories; expected one of them (seft simulate keeps no bag: its '
                    'report.md and report.html are in its output directory)')
            out += [d / 'bag' for d in runs]
    return out


def _runs_without_bag(folder: Path) -> list[Path]:
    """The run directories of a folder of runs (a ``params.yaml`` there) without a bag."""
    try:
        entries = sorted(folder.iterdir(), key=_natural_key)
    except OSError:
        return []
    return [d for d in entries if d.is_dir() and (d / 'params.yaml').is_file()
            and not _is_bag(d / 'bag')]


def _recorded_order(folder: Path, data: list[RunData]) -> list[RunData]:
    """The runs of a folder in the order its command ran and numbered them (run 1, 2, ...:
    the entries of the folder's ``summary.json``, matched by record, predictor and alpha as
    the summary names them), not the directory listing's (``structure_adaptive`` before
    ``structure_model``). `data` as given when the folder has no summary or its entries do
    not name each run once."""
    try:
        entries = json.loads((folder / 'summary.json').read_text())['runs']
        keys = [(e['record'], e['predictor'], None if e['alpha'] is None else float(e['alpha']))
                for e in entries]
    except (OSError, ValueError, KeyError, TypeError):
        return data

    def key(rd):
        rigs = list(rd.rigs.values())
        alpha = rigs[0].params.get('alpha') if len(rigs) == 1 else None
        return (rd.record_name or rd.params.get('record', ''), rd.params.get('predictor'),
                None if alpha is None else float(alpha))
    index = {k: i for i, k in enumerate(keys)}
    ours = [key(rd) for rd in data]
    if len(index) != len(keys) or len(set(ours)) != len(ours) or not all(
            k in index for k in ours):
        return data
    return sorted(data, key=lambda rd: index[key(rd)])


def compare_bags(*, bags: list[str], out_dir: Path, title: str = '',
                 replay_timing: bool = False,
                 progress: Callable[[str], None] = lambda line: None) -> Result:
    """Read bags and write the comparison report against the analytical reference.

    Each path is a bag, a run directory or a folder of run directories (:func:`find_bags`;
    a folder's runs numbered as the command that wrote it numbered them, from its
    ``summary.json``): ``seft compare runs/main`` reports a whole sweep, with the table of
    criteria (one row per run) and their plot against alpha per predictor. With
    `replay_timing`, each real-time run of seft's simulated rigs is replayed in process as it
    ran and with every step in time (:func:`~seft_ros.analysis.timing_replay.replay_timing`;
    its line in the report, ``timing_replay`` in the summary; `progress` says which run).

    Raises
    ------
    InputError
        A path is not a readable seft bag, run directory or folder of run directories.
    """
    t0 = time.monotonic()
    data = []
    skipped: list[str] = []         # the runs of a folder not compared, each said why
    seen: set[Path] = set()         # each bag once (given twice, or in a folder given too)
    for text in bags:
        found = []
        for b in find_bags([text]):
            if b.resolve() in seen:
                progress(f'WARNING: {b}: given more than once: compared once')
                continue
            seen.add(b.resolve())
            found.append(b)
        if not found:
            continue
        if Path(text) in found or Path(text) / 'bag' in found:
            data += [read_run(b) for b in found]      # a bag or run directory named: its own
            continue
        # a folder of runs: a run without a readable bag is said and left out, the rest
        # compared (before: a run whose bag/ was missing left the report silently, and one
        # unreadable bag stopped the whole folder; a new user, session 36)
        for run_dir in _runs_without_bag(Path(text)):
            skipped.append(f'{run_dir}: no bag (bag/ missing or empty)')
            progress(f'WARNING: {skipped[-1]}: not compared')
        runs = []
        for b in found:
            try:
                runs.append(read_run(b))
            except InputError as exc:
                skipped.append(str(exc))
                progress(f'WARNING: {exc}: not compared')
        if not runs:
            raise InputError(f'{text}: no run of the folder has a readable bag (above)')
        data += _recorded_order(Path(text), runs)
    for rd in data:
        # the pre-run guard's prediction, as seft run put it in the summary (deterministic:
        # the run's parameters are in its bag)
        try:
            rd.extra['stability'] = stability_entry(guard_check(rd.params))
        except SeftError:
            pass
        # and its pre-run range check: the run's record as seft run prepared it, or where it
        # cannot be read here, the record as the bag holds it (all of a run that completed)
        from seft_ros.analysis.range_check import range_check
        # what the run read from its record file and how it scaled it, as seft run and
        # simulate report it, where the file is still at the path the run read it from
        # (before: never, a new user missed the scale factor in compare's report, session 36)
        # and only when the file, prepared as the run prepared it, gives the samples the bag
        # holds (an edited file, or another file at the same relative path: not the run's;
        # the session's review)
        try:
            record = prepared_record(rd.params).acceleration_m_s2
            info = record_read(rd.params)
        except SeftError:
            record, info = rd.ground_acceleration_m_s2, None
        n = min(len(record), len(rd.ground_acceleration_m_s2))
        if n and np.array_equal(np.asarray(record[:n], dtype=float),
                                np.asarray(rd.ground_acceleration_m_s2[:n], dtype=float)):
            if info is not None:
                rd.extra['record_read'] = info
        else:
            record = rd.ground_acceleration_m_s2    # the file is not the run's: the bag's
        try:
            rd.extra['range_check'] = range_check(rd.params, record).as_dict()
        except SeftError:
            pass
        if replay_timing:
            from seft_ros.analysis.findings import timing_replay_line
            from seft_ros.analysis.timing_replay import replay_timing as replay
            progress(f'{rd.source}: replaying its timing (two runs in process)')
            try:
                rd.extra['timing_replay'] = replay(rd)
            except SeftError as exc:
                progress(f'{rd.source}: no timing replay: {exc}')
            else:
                progress(f'{rd.source}: ' + (timing_replay_line(rd.extra['timing_replay'])
                                             if rd.extra['timing_replay'] else
                                             'no timing replay (a lockstep run, or a rig '
                                             "that is not seft's simulated one)"))
    return _finish(out_dir, data, title or 'seft compare', t0, tuple(skipped))


def _one_dof(entry: dict) -> bool:
    """Whether a summary entry is of the reference study's one-DOF test."""
    return len((entry.get('structure') or {}).get('dofs') or [None]) == 1


def _rig_name(rig) -> str:
    """A rig in a table: its name, 'rig' for the study's (root namespace), '-' for none."""
    return '-' if rig is None else (rig or 'rig')


#: What the NRMS of :func:`summary_table` and :func:`structure_table` are (their header's
#: last words): each signal's own lag removed, the ``nrms`` of ``summary.json`` (and of the
#: report's per-run tables, beside the common-lag and as-recorded figures).
OWN_LAG_NOTE = ("(NRMS: each signal after removing its own lag; after the displacement's lag "
                'and as recorded: summary.json, report.md)')


def structure_table(summary: list[dict]) -> str:
    """A plain-text table of summary entries per degree of freedom, for any runs: one line
    per run and degree of freedom (NRMS of displacement, acceleration, floor acceleration and
    interface force [%], peak ratios of displacement and floor acceleration), then one line
    per run and rig with the criteria J1 [ms], J2-J5 [%] and, in real time, the timing."""
    def pct(c, key='nrms'):
        v = (c or {}).get(key)
        return f'{100 * v:8.2f}' if v is not None else f'{"-":>8}'

    def ratio(c):
        v = (c or {}).get('peak_ratio')
        return f'{v:7.3f}' if v is not None else f'{"-":>7}'
    lines = [f'{"run":>3} {"predictor":>10} {"stable":>7} {"abort_s":>8} {"dof":>12} '
             f'{"rig":>10} {"nrms_x%":>8} {"nrms_a%":>8} {"nrms_fa%":>8} {"nrms_f%":>8} '
             f'{"peak_x":>7} {"peak_fa":>7}  {OWN_LAG_NOTE}']
    for i, e in enumerate(summary, start=1):
        abort = f'{e["unstable_at_s"]:8.3f}' if e['unstable_at_s'] is not None else f'{"-":>8}'
        for dof in e['structure']['dofs']:
            d = e['dofs'][dof]
            lines.append(f'{i:3d} {e["predictor"]:>10} {_stable_cell(e):>7} {abort} '
                         f'{dof[:12]:>12} {_rig_name(d["rig"])[:10]:>10} '
                         f'{pct(d["displacement"])} {pct(d["acceleration"])} '
                         f'{pct(d["floor_acceleration"])} {pct(d["interface_force"])} '
                         f'{ratio(d["displacement"])} {ratio(d["floor_acceleration"])}')
    lines.append(f'{"run":>3} {"rig":>10} {"J1_ms":>7} {"J2%":>8} {"J3%":>8} {"J4%":>8} '
                 f'{"J5%":>8} {"lat50ms":>8} {"lat99ms":>8} {"stale%":>8}')
    notes: list[str] = []
    for i, e in enumerate(summary, start=1):
        t = e.get('timing')
        for rig, info in e['rigs'].items():
            c = info['criteria']
            cells = ' '.join(f'{c[k]:8.2f}' if c.get(k) is not None else f'{"-":>8}'
                             for k in ('J2', 'J3', 'J4', 'J5'))
            j1 = f'{c["J1"]:7.2f}' if c.get('J1') is not None else f'{"-":>7}'
            # each rig its own stale fraction (its node's timing), not the run's (a new user
            # read the run's figure repeated for each rig; session 39)
            own = ((t or {}).get('nodes') or {}).get(f'{rig}/rig' if rig else 'rig') or {}
            stale = own.get('stale_fraction', (t or {}).get('stale_command_fraction'))
            timing = (f' {t["loop_latency_ms"]["p50"]:8.3f} {t["loop_latency_ms"]["p99"]:8.3f}'
                      f' {100 * stale:8.2f}' if t and stale is not None else '')
            lines.append(f'{i:3d} {_rig_name(rig)[:10]:>10} {j1} {cells}{timing}')
        # the runs' notes below the table, not between its rows (a new user, session 35)
        if e.get('abort_reason'):
            notes.append(f'note: run {i} ({e["predictor"]}): aborted: {e["abort_reason"]}'
                         + _watchdog_hint(e.get('mode'), e['abort_reason']))
        if (e.get('link') or {}).get('warning'):
            notes.append(f'note: run {i} ({e["predictor"]}): {e["link"]["warning"]}')
        notes += _accuracy_notes(f'run {i} ({e["predictor"]})', e)
        notes += [f'note: run {i} ({e["predictor"]}): {line}' if not line.startswith(' ')
                  else line for line in _pushover_lines(e)]
    return '\n'.join(lines + notes)


def _pushover_lines(entry: dict) -> list[str]:
    """The console's lines on what an OpenSees part's pushover found (none: no OpenSees
    model, or the pushover not run)."""
    pushover = (entry.get('opensees') or {}).get('pushover')
    if not pushover or not pushover.get('ran'):
        return []
    from seft_ros.opensees.report import pushover_lines
    return pushover_lines(pushover)


def _stable_cell(entry: dict) -> str:
    """The table's ``stable`` cell: True, False, or ``flagged`` for a stable run with flags
    (``note:`` lines below say why)."""
    return 'flagged' if entry.get('stable') and entry.get('flags') else str(entry['stable'])


#: What a real-time run stopped by one of its watchdogs is told (:func:`_watchdog_hint`).
WATCHDOG_HINT = ('; a watchdog ends a real-time run whose host stalls longer than its limit '
                 '(watchdog_timeout_s, 20 ms by default, is meant for a real-time kernel): on '
                 'a shared or virtual machine try --set watchdog_timeout_s=0.2')


def _watchdog_hint(mode, reason) -> str:
    """:data:`WATCHDOG_HINT` for a run of `mode` 'realtime' whose abort `reason` is a
    watchdog's, else '' (4 of 5 of a new user's runs on a shared host were stopped by 21-31
    ms stalls and nothing named the parameter; session 39)."""
    return WATCHDOG_HINT if mode == 'realtime' and 'watchdog:' in str(reason or '') else ''


def _accuracy_notes(who: str, entry: dict) -> list[str]:
    """``note:`` lines of a summary entry's flags and samples at a sensor's range (issue
    39)."""
    from seft_ros.analysis.findings import bridge_lines, sensor_range_lines
    lines = [f'note: {who}: flagged: {flag}' for flag in entry.get('flags') or ()
             if entry.get('stable')]
    lines += [f'note: {who}: {line}'
              for line in sensor_range_lines(entry.get('sensor_range') or {})]
    lines += [f'note: {who}: WARNING: {line}'
              for kind, line in bridge_lines(entry.get('udp_bridge') or {})
              if kind != 'counts']
    return lines


def summary_table(summary: list[dict]) -> str:
    """A plain-text table of summary entries (one line per run); real-time runs add the loop
    latency (p50, p99), missed deadlines and stale commands; runs with a nonlinear specimen
    (``"nonlinear"`` of the entry) add the displacement NRMS with the drift removed and the
    residual displacement of test and reference [mm]. Below it, one ``note:`` line per
    run whose recording did not end with the run (``"recording"`` of the entry: the recorder
    killed, the bag recovered; or stopped) or has a gap (steps after it not analysed).
    With a structure test among them (more than one degree of freedom): ``structure_table``
    of every run."""
    if not all(_one_dof(e) for e in summary):
        return structure_table(summary)
    head = (f'{"alpha":>6} {"rig":>14} {"predictor":>10} {"stable":>7} {"abort_s":>8} '
            f'{"lag_ms":>7} {"nrms_x%":>8} {"nrms_a%":>8} {"nrms_f%":>8} {"peak_x":>7} '
            f'{"peak_a":>7} {"peak_f":>7}')
    note = f'  {OWN_LAG_NOTE}'
    records = len({e.get('record') for e in summary}) > 1
    if records:
        head += f' {"record":>24}'
    timed = any(e.get('timing') for e in summary)
    if timed:
        head += f' {"lat50ms":>8} {"lat99ms":>8} {"missed%":>8} {"stale%":>8}'
    nonlinear = any(e.get('nonlinear') for e in summary)
    if nonlinear:
        head += f' {"nrms_xr%":>8} {"xres_mm":>8} {"xres_ref":>8}'
    lines = [head + note]

    def pct(v):
        return f'{100 * v:8.2f}' if v is not None else f'{"-":>8}'

    def num(v, w=7):
        return f'{v:{w}.3f}' if v is not None else f'{"-":>{w}}'

    def mm(v):
        return f'{1000 * v:8.2f}' if v is not None else f'{"-":>8}'

    for e in summary:
        abort = f'{e["unstable_at_s"]:8.3f}' if e['unstable_at_s'] is not None else f'{"-":>8}'
        lag = f'{1000 * e["lag_s"]:7.2f}' if e['lag_s'] is not None else f'{"-":>7}'
        lines.append(
            f'{e["alpha"]:6g} {e["rig"]:>14} {e["predictor"]:>10} {_stable_cell(e):>7} '
            f'{abort} {lag} {pct(e["nrms"]["displacement"])} {pct(e["nrms"]["acceleration"])} '
            f'{pct(e["nrms"]["force"])} {num(e["peak_ratio"]["displacement"])} '
            f'{num(e["peak_ratio"]["acceleration"])} {num(e["peak_ratio"]["force"])}')
        if records:
            lines[-1] += f' {str(e.get("record"))[:24]:>24}'
        if timed:
            t = e.get('timing')
            lines[-1] += (f' {num(t["loop_latency_ms"]["p50"], 8)} '
                          f'{num(t["loop_latency_ms"]["p99"], 8)} '
                          f'{pct(t["missed_deadline_fraction"])} '
                          f'{pct(t["stale_command_fraction"])}' if t else '')
        if nonlinear:
            nl = e.get('nonlinear') or {}
            res = nl.get('residual_displacement_m') or {}
            lines[-1] += (f' {pct(nl.get("nrms_displacement_residual_removed"))} '
                          f'{mm(res.get("test"))} {mm(res.get("reference"))}' if nl
                          else f' {"-":>8} {"-":>8} {"-":>8}')
    for i, e in enumerate(summary, start=1):
        if (e.get('link') or {}).get('warning'):
            lines.append(f'note: run {i} (alpha {e["alpha"]:g}, {e["predictor"]}): '
                         f'{e["link"]["warning"]}')
        rec = e.get('recording') or {}
        if rec.get('end') in RECORDING_CUT_SHORT or rec.get('gap_at_step') is not None:
            lines.append(f'note: run {i} (alpha {e["alpha"]:g}, {e["predictor"]}): '
                         f'{rec.get("note")}')
        lines += _accuracy_notes(f'run {i} (alpha {e["alpha"]:g}, {e["predictor"]})', e)
    return '\n'.join(lines)


def criteria_table(summary: list[dict]) -> str:
    """A plain-text table of the RTHS benchmark's criteria (``"criteria"`` of each summary
    entry): J1 [ms], J2-J5 [%], and the NRMS of every signal after removing the common
    (displacement) lag [%]. With a structure test among them: empty (the criteria, per rig,
    are in ``structure_table``)."""
    if not all(_one_dof(e) for e in summary):
        return ''
    head = (f'{"alpha":>6} {"predictor":>10} {"J1_ms":>6} {"J2%":>8} {"J3%":>8} {"J4%":>8} '
            f'{"J5%":>8} {"nrms_x%":>8} {"nrms_a%":>8} {"nrms_f%":>8}  (criteria: Silva et al. '
            '2020; NRMS after removing the displacement lag from every signal)')
    lines = [head]

    def cell(v, w=8, spec='.2f'):
        return f'{v:{w}{spec}}' if isinstance(v, (int, float)) else f'{"-":>{w}}'

    for e in summary:
        c = e.get('criteria') or {}
        n = e.get('nrms_common_lag') or {}
        lines.append(
            f'{e["alpha"]:6g} {e["predictor"]:>10} {cell(c.get("J1"), 6, ".1f")} '
            + ' '.join(cell(c.get(k)) for k in ('J2', 'J3', 'J4', 'J5')) + ' '
            + ' '.join(cell(100 * n[s] if isinstance(n.get(s), (int, float)) else None)
                       for s in ('displacement', 'acceleration', 'force')))
    return '\n'.join(lines)


def parameter_names() -> list[str]:
    """Every parameter name (for ``--set`` completion and checks)."""
    return [s.name for s in parameters.SCHEMA]


# -- stability map and the pre-run guard ------------------------------------------------------

def actuator_velocity_limit_m_s(params) -> float | None:
    """Largest piston velocity the rig's actuator delivers [m/s] (None: not declared):
    :func:`seft_ros.analysis.range_check.actuator_velocity_limit_m_s`."""
    from seft_ros.analysis.range_check import actuator_velocity_limit_m_s as limit
    return limit(params)



def check_realtime_rigs(runs: list[dict]) -> None:
    """Build each simulated rig of the real-time runs as its rig node will
    (:class:`~seft_plant_sim.realtime.WallClockRig`), so that a rig that cannot run on the
    wall clock is refused before any node starts.

    Raises
    ------
    ParameterError
        The rig's one-line reason, with the rig's name.
    """
    from seft_plant_sim.realtime import WallClockRig
    from seft_ros.core.structure import test_setup
    for p in runs:
        if p.get('mode') != 'realtime':
            continue
        for rig, rp in test_setup(p).rig_params.items():
            if rp.get('rig_interface', 'simulated') != 'simulated':
                continue
            try:
                WallClockRig(rp)
            except ParameterError as exc:
                raise ParameterError(f'rig {rig}: {exc}' if rig else str(exc)) from None


class RangeRefusedError(SeftError):
    """``--strict``: a run's reference exceeds a rig's sensor range or actuator capacity."""


def check_settings(*, runs: list[dict], progress: Callable[[str], None] = print) -> None:
    """One ``settings:`` line before the runs per combination of a run's settings that the
    docs' tables show costs accuracy (:func:`seft_ros.core.specimen_settings.costly_settings`;
    a line shared by several runs once, with their labels)."""
    from seft_ros.core.specimen_settings import costly_settings
    lines: dict[str, list[str]] = {}
    for p, label in zip(runs, run_labels(runs)):
        for line in costly_settings(p):
            lines.setdefault(line, []).append(label)
    for line, labels in lines.items():
        progress(f'settings: [{", ".join(labels)}] {line}' if len(runs) > 1 else
                 f'settings: {line}')


def check_ranges(*, runs: list[dict], strict: bool = False, force: bool = False,
                 progress: Callable[[str], None] = print) -> list:
    """Before the runs: each rig's peaks of the analytical reference against its sensors'
    ranges and its actuator's capacity (:func:`seft_ros.analysis.range_check.range_check`).

    One line per channel that will be exceeded (``range check: [run] rig, channel: the
    reference peaks at ..., beyond the ... of ...; the largest amplitude that fits: ...``), a
    line shared by several runs once with their labels; `strict` (``--strict``) refuses the
    runs instead. A real-time run (``mode: realtime``: a rig on the wall clock, a lab's
    hardware) whose reference exceeds its *actuator's* capacity (force, stroke or velocity:
    ``actuator *`` channels) is refused unless `force` (``--force``): the interlock would stop
    it (the operations tester's run needing 4 times the stroke and 1.8 times the force was
    stopped at 0.86 s); a sensor's range stays a warning there (the run counts what clips).
    A run with a plug-in's model (:mod:`seft_ros.core.models`) is first checked
    by its plug-in's ``check_runs`` (OpenSees: :func:`seft_ros.opensees.checks.check_runs`;
    refused in one line where it cannot run as configured); its range check reads its
    program's own analysis (OpenSees': a few seconds for a frame, which the report then
    takes back).

    Returns
    -------
    list of RangeCheck
        One per run (for ``summary.json``, ``extra['range_check']``).

    Raises
    ------
    RangeRefusedError
        `strict` and a channel exceeded, or a real-time run beyond its actuator's capacity
        and not `force` (the message is the first such line and how many more).
    InputError, ParameterError
        Bad record or parameter.
    """
    from seft_ros.analysis.range_check import range_check
    kinds = {structure_of(p).model_kind for p in runs if has_structure(p)} - {None}
    for kind in sorted(kinds):
        check = getattr(model_plugin(kind), 'check_runs', None)
        if check is not None:
            check(runs, progress=progress)
    checks, lines, beyond = [], {}, {}
    for p, label in zip(runs, run_labels(runs)):
        check = range_check(p, prepared_record(p).acceleration_m_s2)
        checks.append(check)
        for peak in check.exceeded:
            line = check.line(peak)
            lines.setdefault(line, []).append(label)
            if p.get('mode') == 'realtime' and peak.channel.startswith('actuator '):
                beyond.setdefault(line, []).append(label)

    def labelled(found):
        return [f'[{", ".join(labels)}] {line}' if len(runs) > 1 else line
                for line, labels in found.items()]
    shown = labelled(lines)
    every = _fits_every_run(checks)
    if strict and shown:
        more = f' (and {len(shown) - 1} more{every})' if len(shown) > 1 else ''
        raise RangeRefusedError(f'range check: {shown[0]}{more}; refused (--strict): lower '
                                'the amplitude or run without --strict')
    if beyond and not force:
        refused = labelled(beyond)
        more = f' (and {len(refused) - 1} more)' if len(refused) > 1 else ''
        raise RangeRefusedError(
            f"range check: {refused[0]}{more}; refused: a real-time run beyond its actuator's "
            'capacity, which the interlock would stop; lower the amplitude, or --force to '
            'run it anyway')
    for line in shown:
        progress(f'range check: {line}')
    if len(shown) > 1 and every:
        progress(f'range check: {every[2:]}')
    # the runs it could not check, said (a model that does not build or converge): the run
    # then has no pre-run check, nor does --strict refuse it
    unchecked: dict[str, list] = {}
    for check, label in zip(checks, run_labels(runs)):
        if check.note and not check.note.startswith('an identification run'):
            unchecked.setdefault(check.note, []).append(label)
    for note, labels in unchecked.items():
        who = f' [{", ".join(labels)}]' if len(runs) > 1 else ''
        progress(f'range check{who}: not made, {note}: the sensors and the actuator are '
                 'watched during the run only' + (' (--strict cannot refuse it)'
                                                  if strict else ''))
    return checks


def _fits_every_run(checks) -> str:
    """``'; the largest amplitude that fits them all: amplitude_N 180.9 N'``: the least of
    the exceeded channels' (:meth:`~seft_ros.analysis.range_check.RangeCheck.fits`) over the
    runs of a sweep, when more than one channel or run is exceeded and every run scales its
    record by the same option (``amplitude_N`` or ``scale_factor``); '' otherwise. Each line
    gives its own channel's and run's figure, which another line's may not fit (a lab that
    retried a refused sweep at the first line's amplitude was refused again on the next run).
    """
    fits = [(c.scale_name, c.fits(p), c.linear) for c in checks for p in c.exceeded]
    names = {c.scale_name for c in checks}
    if len(fits) < 2 or len(names) != 1:
        return ''
    name = names.pop()
    least = min(f for _, f, _ in fits)
    unit = ' N' if name == 'amplitude_N' else ''
    estimate = ('' if all(linear for _, _, linear in fits)
                else ' (scaled linearly: a yielding member makes it an estimate)')
    return f'; the largest amplitude that fits them all: {name} {least:.4g}{unit}{estimate}'


def check_stability(*, runs: list[dict], force: bool = False,
                    progress: Callable[[str], None] = print) -> list[stability.StabilityCheck]:
    """Refuse (or with `force` warn about) runs predicted unstable as configured, or whose
    declared specimen uncertainty exceeds their robustness margin.

    Each run with a linear rig and a compensator with a linear form is checked by
    :func:`seft_ros.core.stability.check_run` (spectral radius of the sampled loop as
    configured) with its robustness margin (the specimen stiffness range, as a fraction of
    the declared one, over which it stays stable: one line per run through `progress`)
    and, for the study's one-DOF linear test on a record, its NRMS displacement error
    predicted on the loop's model for the record's spectrum (:func:`guard_check`; on the
    same line); the others get a note. A run with ``specimen_uncertainty`` u > 0 whose
    margin does not hold ``1 +- u`` is refused like an unstable one.

    Returns
    -------
    list of StabilityCheck
        One per run (with its ``margin``).

    Raises
    ------
    PredictedUnstableError
        A run is predicted unstable, or its uncertainty exceeds its margin, and `force` is
        False (message of the first such run).
    ParameterError
        A run cannot be set up (its compensator's calibration; named by its label when there
        are several runs).
    """
    spectra: dict = {}
    labels = run_labels(runs)
    checks = []
    for p, label in zip(runs, labels):
        try:
            checks.append(guard_check(p, spectra))
        except ParameterError as exc:
            # one run of several that cannot be set up (its compensator's calibration): named
            # (a new user's `model` of a batch with `adaptive` refused all in a line naming
            # none; session 38)
            if len(runs) > 1:
                raise ParameterError(f'[{label}] {exc} (the other runs: run them without '
                                     'this one)') from None
            raise
    refused = []
    for p, c, label in zip(runs, checks, labels):
        if c.stable is None:
            progress(f'note: {c.message}')
        if c.margin is not None:
            progress(f'robustness: [{label}] {c.margin.text()}' + predicted_error_text(c))
        if c.stable is False:
            refused.append(c.message)
            continue
        u = float(p.get('specimen_uncertainty', 0.0) or 0.0)
        if u > 0 and c.margin is not None and c.margin.quantity != 'stiffness':
            refused.append(
                f'[{label}] parameter specimen_uncertainty={u:g}: the specimen stiffness is '
                "checked on seft's rig model; a plant model of data (plant_model) has its "
                'specimen inside it: identify the rig with the specimen as tested, or use '
                'predictor adaptive (set specimen_uncertainty to 0)')
            continue
        if u > 0 and c.margin is not None and not c.margin.covers(u):
            refused.append(
                f'[{label}] parameter specimen_uncertainty={u:g}: the specimens may be '
                f'{1 - u:.3g}-{1 + u:.3g} x their declared stiffness, but predictor '
                f'{p["predictor"]} stays stable only for {c.margin.text(bare=True)} '
                '(its robustness margin); use predictor adaptive, narrow the uncertainty '
                '(identify the specimens first: seft identify)')
    if refused and not force:
        more = f' (and {len(refused) - 1} more run(s))' if len(refused) > 1 else ''
        raise stability.PredictedUnstableError(
            f'{refused[0]}{more}; use --force to run it anyway')
    for message in refused:
        progress(f'warning: {message}; running it anyway (--force)')
    return checks


#: The parameters the played record's spectrum depends on (the key of
#: :func:`guard_check`'s spectra: the runs of one configuration share one).
_RECORD_KEYS = ('record', 'dt', 'mass_kg', 'amplitude_N', 'scale_factor', 'time_scale',
                'duration_s', 'record_resampling', 'n_steps')


def _own_controller_line(rig: str, params: dict, plant) -> str:
    """The line of ``seft design`` on a rig's own controller (``force_controller
    transfer_function``): its crossover and margins on the plant model and whether it closes
    a stable force loop there (no command said so: a new user was sent from seft identify to
    seft design, which ignored it, and from there to seft stability; session 38)."""
    from seft_ros.core.controller import ForceServoController
    from seft_ros.core.force_design import closed_loop_stable, plant_margins
    ctrl = ForceServoController.from_parameters(params)
    m = plant_margins(plant, ctrl)
    gm = 'inf' if math.isinf(m.gain_margin) else f'{m.gain_margin:.3g}'
    stable = closed_loop_stable(plant, ctrl.bz, ctrl.az)
    return (f"{f'rig {rig}: ' if rig else ''}its own controller (force_controller_tf) on the "
            f'plant model: crossover {m.crossover_hz:.3g} Hz ({m.crossovers} gain '
            f'crossover(s)), phase margin {m.phase_margin_deg:.3g} deg at '
            f'{m.phase_margin_hz:.3g} Hz, gain margin {gm}; its force loop is '
            + ('stable' if stable else 'UNSTABLE') + "; seft's own design follows")


def guard_check(params: dict, spectra: dict | None = None) -> stability.StabilityCheck:
    """The pre-run guard's prediction of one run: stability, robustness margin and, for
    the study's one-DOF linear test on a record it plays long enough
    (:func:`played_record_s`, :data:`MIN_PREDICTED_PLAY_S`), its NRMS displacement error;
    a shorter run gets a note instead (``StabilityCheck.error_note``).

    :func:`seft_ros.core.stability.check_run` with ``margin`` and ``error``, the error
    weighed with the spectrum of the record the run plays
    (:func:`seft_ros.core.force_design.played_record_spectrum`, as the design weighs its
    own prediction; the Kanai-Tajimi ground where the record cannot be read here).

    Parameters
    ----------
    params : dict
        A run's resolved parameters.
    spectra : dict, optional
        The records' spectra already computed, by their parameters (filled here).

    Returns
    -------
    StabilityCheck
    """
    spectrum, played = None, None
    if not identification_run(params):
        from seft_ros.core.force_design import played_record_spectrum
        key = tuple(repr(params.get(k)) for k in _RECORD_KEYS)
        spectra = {} if spectra is None else spectra
        if key not in spectra:
            played = played_record_s(params)
            if played is None and not float(params.get('duration_s', 0.0) or 0.0) > 0:
                played = (math.inf, math.inf)   # the whole record, not readable here
            spectra[key] = (played_record_spectrum(params)[0], played)
        spectrum, played = spectra[key]
    check = stability.check_run(params, margin=True, error=played is not None,
                                spectrum=spectrum)
    played_s, _ = played or (math.inf, math.inf)
    if played_s < MIN_PREDICTED_PLAY_S and math.isfinite(check.predicted_error):
        check = replace(check, predicted_error=math.nan, error_note=(
            f'no NRMS x prediction: the run plays {played_s:.3g} s of its record, too short '
            "for the guard's steady-state prediction (its start from rest; "
            f'{MIN_PREDICTED_PLAY_S:g} s or more)'))
    return check


#: A run gets the guard's NRMS prediction, and the flag of an error beyond it, when it
#: plays at least this long of its record [s] (cut by ``duration_s`` or not: a record of
#: 0.05 s was predicted at 0.4 % and erred 99.7 %, flagged with a valve-gain advice).
#: Its start from rest errs against a reference still small: measured on the study's rig
#: (``none`` and ``model``, alpha 0.5 and 1, 500 N) on the default record, El Centro 180 and
#: Kobe KJMA 000 and 090, runs of 4, 8 and 15 s erred 0.29-1.06 x the prediction, runs of
#: 2 s up to 44 x (Kobe's quiet lead-in); on the delay rig (``none`` and ``model`` at alpha
#: 0, ``none`` at 0.5) runs of 6 s 0.97-2.0 x but for one 19 x within the accurate test's
#: 1 % (0.55 %), of 4 s up to 20 x (1.15 %: flagged), of 1 s up to 200 x. Before, a cut run
#: got no prediction however long: a lab plant's valve gain 2 % off erred 45.8 % of x over 15
#: of El Centro's 26.9 s, "stable" with no flag.
MIN_PREDICTED_PLAY_S = 6.0


def played_record_s(params: dict) -> tuple[float, float] | None:
    """How long a run plays of its record, and the record's length [s].

    Parameters
    ----------
    params : dict
        A run's resolved parameters (``record``, its scaling, ``dt``, ``duration_s``).

    Returns
    -------
    (float, float) or None
        ``(played, whole)`` [s]; None where the record cannot be read here (the run says
        why).
    """
    from seft_ros.core.ground_motion import prepared_record
    dt = float(params['dt'])
    try:
        played = prepared_record(dict(params, excitation='none', n_steps=0))
        whole = (prepared_record(dict(params, excitation='none', n_steps=0, duration_s=0.0))
                 if float(params.get('duration_s', 0.0) or 0.0) > 0 else played)
    except (SeftError, KeyError, ValueError, OSError):
        return None
    return len(played.acceleration_m_s2) * dt, len(whole.acceleration_m_s2) * dt


def predicted_error_text(check: stability.StabilityCheck) -> str:
    """'; NRMS x predicted 0.42 % on the loop's model (record default)' for a check with
    a finite predicted error, '' otherwise."""
    e = check.predicted_error
    if not math.isfinite(e):
        return f'; {check.error_note}' if check.error_note else ''
    return f"; NRMS x predicted {100 * e:.2g} % on the loop's model ({check.error_spectrum})"


def stability_entry(check: stability.StabilityCheck) -> dict:
    """A run's pre-run prediction for its ``summary.json`` (``extra['stability']``): the
    verdict, spectral radius, largest stable alpha, message, robustness margin and
    ``predicted_error`` (``{'displacement': NRMS [-], 'spectrum': ...}``, or None where the
    guard predicts none: :func:`guard_check`)."""
    def num(v):
        return None if v != v else ('inf' if v == float('inf') else float(v))
    e = check.predicted_error
    return {'predicted_stable': check.stable, 'spectral_radius': num(check.spectral_radius),
            'boundary': num(check.boundary_alpha), 'message': check.message,
            'robustness_margin': None if check.margin is None else check.margin.to_json(),
            'predicted_error': ({'displacement': float(e), 'spectrum': check.error_spectrum}
                                if math.isfinite(e) else None),
            'error_note': check.error_note or None}


class StabilityResult:
    """What ``seft stability`` produced: the map, the configured alphas and the files."""

    def __init__(self, smap: stability.StabilityMap, alphas: list[float], tau_s: float,
                 json_path: Path, png_path: Path):
        self.map = smap
        self.alphas = alphas
        self.tau_s = tau_s
        self.json_path = json_path
        self.png_path = png_path


#: Default delay range of the map per rig [s]: (first, last); 0.5 ms spacing.
_TAU_RANGE = {'delay': (0.0005, 0.02), 'servohydraulic': (0.0, 0.01)}


def stability_report(*, out_dir: Path, config: str | None = None,
                     overrides: dict[str, Any] | None = None,
                     predictors: list[str] | None = None, tau_min: float | None = None,
                     tau_max: float | None = None, points: int | None = None,
                     alpha_max: float = 3.0) -> StabilityResult:
    """Largest stable alpha over the rig's delay per predictor: ``stability.json`` and
    ``stability.png`` in `out_dir`.

    Parameters
    ----------
    out_dir : Path
        Output directory.
    config, overrides
        As :func:`build_runs`; the rig (``rig_model``) and the other parameters of the map,
        the configured alpha(s) and delay are marked on the plot.
    predictors : list of str, optional
        Default: every registered predictor.
    tau_min, tau_max : float, optional
        Delay range [s] (``tau_s`` of the delay rig, ``io_latency_s`` of the servohydraulic
        rig); default 0.5-20 ms (delay) or 0-10 ms (servohydraulic).
    points : int >= 2, optional
        Number of delays (default: 0.5 ms spacing; a structure's map, which takes seconds
        a point: 6).
    alpha_max : float > 0
        Upper end of the search in alpha.

    Raises
    ------
    InputError, ParameterError
        Bad configuration, range or predictor name.
    """
    runs = build_runs(config=config, overrides=overrides)
    params = runs[0]
    structure = has_structure(params)
    rig = params['rig_model']
    knob = stability.DELAY_PARAMETER.get(rig)
    if knob is None:
        raise ParameterError(f'parameter rig_model={rig!r}: seft stability maps the delay of '
                             "seft's own rig models ("
                             + ', '.join(repr(r) for r in stability.DELAY_PARAMETER)
                             + '); a plant model carries its delay: seft simulate or run '
                             'checks its loop before the test and refuses one predicted '
                             'unstable')
    lo, hi = _TAU_RANGE[rig]
    lo = lo if tau_min is None else float(tau_min)
    hi = hi if tau_max is None else float(tau_max)
    low_ok = lo > 0 if rig == 'delay' else lo >= 0
    if not (low_ok and hi > lo):
        raise ParameterError(f'--tau-min {lo:g} --tau-max {hi:g}: expected '
                             f'{"0 <" if rig == "delay" else "0 <="} tau-min < tau-max')
    # a structure's map (coupling scale over the delay) takes seconds a point: fewer points
    default_n = int(round((hi - lo) / 0.0005)) + 1 if not structure else 6
    n = default_n if points is None else int(points)
    if n < 2:
        raise ParameterError(f'--points {n}: expected >= 2')
    if not alpha_max > 0:
        raise ParameterError(f'--alpha-max {alpha_max:g}: expected > 0')
    names = list(predictors or PREDICTORS)
    for name in names:
        if name not in PREDICTORS:
            choices = ', '.join(repr(c) for c in PREDICTORS)
            raise ParameterError(f'predictor {name!r}: expected one of {choices}')
    if not structure and rig == 'servohydraulic':
        # a sample period too long for the force loop itself: said at once, not after a map
        alone = stability.check_run(dict(params, alpha=0.0, predictor='none'))
        if alone.stable is False:
            raise ParameterError(alone.message)
    taus = np.linspace(lo, hi, n)
    smap = stability.stability_map(params, taus, names, alpha_max=alpha_max)
    # a structure's runs are at coupling scale 1
    alphas = [1.0 if structure else float(p['alpha']) for p in runs]
    json_path = Path(out_dir) / 'stability.json'
    doc = smap.to_json()
    doc['configured'] = {'alpha': alphas, knob: float(params[knob])}
    json_path.write_text(json.dumps(doc, indent=1) + '\n')
    if structure:
        doc['quantity'] = 'largest stable coupling scale of the computational part'
        json_path.write_text(json.dumps(doc, indent=1) + '\n')
    png_path = _plot_stability(smap, alphas, float(params[knob]), Path(out_dir) / 'stability.png',
                               structure=structure)
    return StabilityResult(smap, alphas, float(params[knob]), json_path, png_path)


def _plot_stability(smap: stability.StabilityMap, alphas: list[float], tau_s: float,
                    path: Path, *, structure: bool = False) -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # only for the figure
    from matplotlib.figure import Figure
    fig = Figure(figsize=(7.5, 4.8))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    t_ms = 1e3 * smap.taus_s
    for i, name in enumerate(smap.predictors):
        if name in smap.notes:
            ax.plot([], [], ' ', label=f'{name}: n/a (nonlinear)')
            continue
        y = np.minimum(smap.boundary_alpha[i], smap.alpha_max)
        ax.plot(t_ms, y, marker='.', label=f'{name}')
    if not structure:
        ax.axhline(1.0, color='k', ls='--', lw=1.0,
                   label='alpha = 1: neutral-type limit (pure delay, no compensation)')
    ax.plot([1e3 * tau_s] * len(alphas), alphas, 'rx', ms=8, label='configured runs')
    label = 'actuator delay tau_s' if smap.rig == 'delay' else 'I/O latency io_latency_s'
    ax.set_xlabel(f'{label} [ms]')
    ax.set_ylabel('largest stable coupling scale' if structure else 'largest stable alpha')
    ax.set_ylim(0.0, smap.alpha_max * 1.02)
    ax.set_title(f'Substructure EFT stability boundary, {smap.rig} rig '
                 f'(stable below the curve; capped at {smap.alpha_max:g})', fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def stability_table(result: StabilityResult) -> str:
    """Plain-text table of the map: delay [ms] and the largest stable alpha per predictor
    ('unstable': already at alpha = 0; '>X': stable up to alpha_max; 'n/a': nonlinear)."""
    smap = result.map
    head = f'{smap.delay_parameter + " [ms]":>17} ' + ' '.join(f'{p:>12}'
                                                              for p in smap.predictors)
    lines = [head]

    def cell(i, j):
        if smap.predictors[i] in smap.notes:
            return 'n/a'
        v = smap.boundary_alpha[i, j]
        if v != v or v == 0.0:
            return 'unstable'
        return f'>{smap.alpha_max:g}' if v == float('inf') else f'{v:.3f}'

    for j, tau in enumerate(smap.taus_s):
        lines.append(f'{1e3 * tau:17.2f} ' + ' '.join(f'{cell(i, j):>12}'
                                                      for i in range(len(smap.predictors))))
    for name, note in smap.notes.items():
        lines.append(f'{name}: {note}')
    return '\n'.join(lines)


def _planned_duration_s(params: dict) -> float | None:
    """The length a run was set up for [s] (``n_steps`` or ``duration_s``; an excitation's
    default when 0), None when it is the record's."""
    dt = float(params.get('dt', 0.0) or 0.0)
    if int(params.get('n_steps', 0) or 0) and dt:
        return int(params['n_steps']) * dt
    duration = float(params.get('duration_s', 0.0) or 0.0)
    if not duration and identification_run(params):
        from seft_ros.core.excitation import DEFAULT_DURATION_S
        return DEFAULT_DURATION_S
    return duration or None


class IdentifyResult:
    """What ``seft identify`` produced: the JSON document and where the files are
    (``kept``: where the parameter file it replaced was kept, None when it replaced none)."""

    def __init__(self, out_dir: Path, document: dict, params_path: Path | None,
                 kept: Path | None = None):
        self.out_dir = out_dir
        self.document = document
        self.params_path = params_path
        self.kept = kept


def keep_previous(path: Path) -> Path | None:
    """Move an existing file `path` aside before it is written anew: to
    ``<stem>.previous-<n><suffix>`` beside it (the first free ``n``), or None when there is
    none. A parameter file of ``seft identify`` holds a lab's identified loop and designed
    controller; writing a new one over it silently lost the one before (a new user
    identified another specimen's runs into the same file)."""
    path = Path(path)
    if not path.is_file():
        return None
    n = 1
    while (kept := path.with_name(f'{path.stem}.previous-{n}{path.suffix}')).exists():
        n += 1
    path.rename(kept)
    return kept


def identify_bags(*, bags: list[str], out_dir: Path, window: str = 'hann',
                  nperseg: int | None = None, noverlap: int | None = None,
                  orders: tuple[int, int] | None = None,
                  params_out: str | None = None) -> IdentifyResult:
    """Identify the rigs from the bags of identification runs (``seft identify``).

    Each rig of each bag is identified from its own signals: its force loop (H1 responses,
    fits, delay, loop margins) and its specimen (``f = m a + c v + k x``). The bags of the
    study's rig give one parameter file for its compensators; the bags of a structure's
    identification run (each rig alone, :func:`seft_ros.core.excitation.rigs_alone`) give
    one ``rigs`` section per rig, for the structure's test (``--params``).

    Parameters
    ----------
    bags : list of str
        Bags, run directories or folders of run directories (:func:`find_bags`).
    out_dir : Path
        Where ``identification.json``, ``identification.md`` and the PNGs go.
    window, nperseg, noverlap
        Welch settings of the H1 estimates (default segment 1024 samples, half overlap).
    orders : (int, int), optional
        Orders (nb, na) of the rational fits (default per kind of run).
    params_out : str, optional
        Write the identified parameters there as a parameter file
        (:func:`~seft_ros.analysis.rig_identification.identified_parameters`): the study's
        rig's closed-loop delay and, from an open-loop bag, its plant model with the force
        controller designed for it (which replaces the configured one) and its
        compensators' settings; or each structure rig's specimen and the same in its
        ``rigs`` section.

    Returns
    -------
    IdentifyResult

    Raises
    ------
    InputError, ParameterError
        Unreadable bag, a run that was aborted (when and why), a run too short for the
        segment length, bad options, bags of the study's rig and of a structure together;
        the message names the bag (and the rig) or the option. With `params_out`: a rig of
        the bags whose open-loop run gave no plant model (its specimen fit's verdict: a
        sensor at its range, a member that yields), or a structure's rig with nothing
        identified: the file would lack it (the report and figures are written first).
    """
    from seft_ros.analysis import rig_identification as ri
    from seft_ros.analysis.identification_report import (
        write_identification,
        write_params_yaml,
        write_rig_params_yaml,
    )
    from seft_ros.analysis.report import software_versions
    if params_out and Path(params_out).is_dir():
        raise InputError(f'--params {params_out}: is a directory; expected the name of the '
                         'parameter file to write')
    idents = []
    kinds = {}
    for path in find_bags(bags):
        rd = read_run(path)
        if not rd.stable:
            planned = _planned_duration_s(rd.params)
            of = f' of {planned:g} s' if planned else ''
            raise InputError(f'{path}: the run was aborted at {rd.unstable_at_s:.3f} s{of} '
                             f'({rd.abort_reason or "no reason recorded"}); identification '
                             'needs a run that completed: fix the cause and record it again')
        kinds[str(path)] = 'study' if rd.is_study else 'structure'
        with single_blas_thread():
            idents += ri.identify_rigs(rd, window=window, nperseg=nperseg or ri.DEFAULT_NPERSEG,
                                       noverlap=noverlap, orders=orders)
    if len(set(kinds.values())) > 1:
        study = next(b for b, k in kinds.items() if k == 'study')
        other = next(b for b, k in kinds.items() if k == 'structure')
        raise InputError(f"{study} is a bag of the study's rig and {other} one of a "
                         "structure's rigs: identify them apart (their parameter files "
                         'differ)')
    structure = 'structure' in kinds.values()
    version = ', '.join(f'{k} {v}' for k, v in software_versions().items())
    if structure:
        per_rig = ri.identified_rig_parameters(idents)
        doc = write_identification(idents, out_dir, rig_parameters=per_rig, version=version)
        identified = {r: v for r, v in per_rig.items()
                      if any(not k.startswith('_') for k in v)}
    else:
        identified = ri.identified_parameters(idents)
        doc = write_identification(idents, out_dir, identified=identified, version=version)
    params_path = None
    if params_out:
        lacking = _rigs_lacking(per_rig if structure else {'': identified},
                                [i.rig for i in idents])
        if lacking:
            raise InputError(f'--params {params_out}: not written: {lacking} (the report: '
                             f'{Path(out_dir) / "identification.md"})')
        if not identified:
            raise InputError(f'--params {params_out}: nothing to write (no closed-loop delay, '
                             'no open-loop run of a valve-driven rig and no linear specimen '
                             'among the bags)' if structure else
                             f'--params {params_out}: nothing to write (no closed-loop delay '
                             'and no open-loop run of a valve-driven rig with a linear '
                             'specimen among the bags)')
        kept = keep_previous(Path(params_out))
        params_path = (write_rig_params_yaml(per_rig, params_out) if structure
                       else write_params_yaml(identified, params_out))
        return IdentifyResult(out_dir, doc, params_path, kept)
    return IdentifyResult(out_dir, doc, params_path)


def _specimen_mismatch(specs) -> list[str]:
    """A WARNING line when the first linear identified specimen of `specs` (``(kind,
    figures)``) differs from the declared one by more than the specimen check's default
    tolerance (``seft_ros.core.monitor.DEFAULT_SPECIMEN_TOLERANCE``, 10 %) in mass
    or stiffness (a new user's plant file of another specimen: 0.04 x the declared
    stiffness, said by nothing until its test was refused)."""
    from seft_ros.core.monitor import DEFAULT_SPECIMEN_TOLERANCE as tolerance
    fit = next((spec for _, spec in specs if spec.get('linear')), None)
    if fit is None:
        return []
    declared = fit['declared']
    ratios = [fit[k] / declared[k] for k in ('mass_kg', 'stiffness_N_per_m')
              if declared.get(k)]
    if all(abs(r - 1.0) <= tolerance for r in ratios):
        return []
    return [f'  WARNING: the identified specimen is {ratios[0]:.3g} x the declared mass and '
            f'{ratios[1]:.3g} x its stiffness (beyond +-{100 * tolerance:g} %): the '
            'specimen on the rig is not the declared one; declare the one identified '
            "(predictor_* or the rig's mass_kg, stiffness_N_per_m), or identify with the "
            'specimen the test is for']


def _rigs_lacking(values: dict[str, dict[str, Any]], rigs: list[str]) -> str:
    """Why the parameter file of ``seft identify`` would lack a rig of the bags, one clause
    per rig ('' when none lacks): a rig with nothing identified, or whose open-loop run gave
    no plant model (``_plant`` 'not identified ...': a structure's test would run it on the
    configured controller, its section silently missing)."""
    out = []
    for rig in dict.fromkeys(rigs):
        own = values.get(rig) or {}
        who = f'rig {rig}' if rig else 'the rig'
        note = str(own.get('_plant', ''))
        if note.startswith('not identified'):
            out.append(f'{who} gets no plant model and no force controller: {note}')
        elif rig and not any(not k.startswith('_') for k in own):
            out.append(f'{who}: nothing identified'
                       + (f" ({own['_specimen']})" if '_specimen' in own else ''))
    return '; '.join(out)


class DesignResult:
    """What ``seft design`` produced: each rig's design, the parameter file and, for a
    structure, each coupled rig's force-loop inverse chosen by rehearsing it
    (:class:`~seft_ros.core.structure_design.InverseChoice`)."""

    def __init__(self, designs: dict, params_path: Path | None, document: dict,
                 inverse_choices: list | None = None):
        self.designs = designs
        self.params_path = params_path
        self.document = document
        self.inverse_choices = list(inverse_choices or [])


def design_controllers(*, config: str | None = None, overrides: dict | None = None,
                       params_files: list[str] | None = None, out: str | None = None,
                       phase_margin_deg: float = 45.0, gain_margin: float = 2.0,
                       crossover_hz: float = 0.0, uncertainty: float = 0.05,
                       progress: Callable[[str], None] = lambda _: None) -> DesignResult:
    """Design each valve-driven rig's force controller from its plant model (``seft design``).

    The plant is the rig's (:func:`seft_ros.core.force_loop.force_loop_plant`: its
    ``plant_model``, written by the lab or by ``seft identify``, else seft's servohydraulic
    rig model with the rig's specimen), the design :func:`seft_ros.core.force_design.
    design_force_controller` with the targets given, its force-loop inverse ranked for the
    spectrum of the record the configuration names (:func:`seft_ros.core.force_design.
    played_record_spectrum`). In a structure each coupled rig's
    force-loop inverse is then chosen by rehearsing the structure's test on the plant
    models (:func:`seft_ros.core.structure_design.choose_structure_inverses`; `progress`
    receives a line per rig).

    Parameters
    ----------
    config, overrides, params_files
        As :func:`build_runs` (the first run's rigs are designed).
    out : str, optional
        Write the designed controllers and the compensators' settings there as a parameter
        file (a structure's: a ``rigs`` section per rig), to layer with ``--params``.
    phase_margin_deg, gain_margin, crossover_hz, uncertainty
        :class:`~seft_ros.core.force_design.DesignTargets`.

    Returns
    -------
    DesignResult

    Raises
    ------
    InputError, ParameterError
        A bad configuration or target, a rig without a model of its force loop (the message
        says to identify it), no valve-driven rig.
    """
    from seft_ros.analysis.identification_report import write_params_yaml, write_rig_params_yaml
    from seft_ros.core.force_design import (
        DesignTargets,
        design_force_controller,
        played_record_spectrum,
    )
    from seft_ros.core.force_loop import force_loop_plant, has_plant_model
    from seft_ros.core.structure import test_setup
    if out and Path(out).is_dir():
        raise InputError(f'--out {out}: is a directory; expected the name of the parameter '
                         'file to write')
    targets = DesignTargets(phase_margin_deg, gain_margin, crossover_hz, uncertainty)
    params = build_runs(config=config, overrides=overrides, params_files=params_files)[0]
    setup = test_setup(params)
    spectrum, note = played_record_spectrum(params)
    designs = {}
    for rig in setup.rig_names:
        rp = setup.rig_params[rig]
        if not parameters.valve_commanded(rp):
            continue
        try:
            plant = force_loop_plant(rp)
        except ParameterError as exc:
            raise ParameterError(f'rig {rig}: {exc}' if rig else str(exc)) from None
        if rp.get('force_controller') == 'transfer_function':
            progress(_own_controller_line(rig, rp, plant))
        designs[rig] = design_force_controller(plant, targets=targets,
                                               ground_spectrum=spectrum,
                                               plant_gain_margin=has_plant_model(rp))
        if note:
            designs[rig].notes.append(note)
    if not designs:
        raise ParameterError('no valve-driven rig in the test (rig_model delay takes the '
                             'reference force: it has no force controller to design)')
    unstable = [r or 'the rig' for r, d in designs.items() if not d.stable]
    if unstable:
        raise ParameterError(f'{", ".join(unstable)}: no controller of seft\'s design closes a '
                             "stable force loop on the plant model; enter the lab's own "
                             '(force_controller transfer_function, force_controller_tf): seft '
                             'design prints its margins on the plant model, and seft simulate '
                             "and run's guard its stability")
    values = {r: dict(d.parameters(), _design=d.summary()
                      + ('' if d.met else ' (targets NOT met: ' + '; '.join(d.notes) + ')'))
              for r, d in designs.items()}
    choices = []
    if not setup.is_study:
        from seft_ros.core.structure_design import choose_structure_inverses
        designed = {r: mapping_values({k: v for k, v in values[r].items()
                                       if not k.startswith('_')}) for r in values}
        choices = choose_structure_inverses(
            params, designed, progress,
            shortest={r: d.shortest_loop_delay_steps for r, d in designs.items()})
        for c in choices:
            values[c.rig].update(c.values)
            values[c.rig]['_design'] += f'; {c.summary()}'
    path = None
    if out:
        path = (write_params_yaml(values[''], out, command='seft design')
                if list(values) == [''] else
                write_rig_params_yaml(values, out, command='seft design'))
    doc = {r: d.to_json() for r, d in designs.items()}
    for c in choices:
        doc[c.rig]['structure_inverse'] = c.to_json()
    return DesignResult(designs, path, doc, choices)


#: The figures ``seft identify`` prints, in order.
_IDENTIFY_FIGURES = ('zero_hz', 'resonance_hz', 'crossover_hz', 'crossovers', 'phase_margin_deg',
                     'phase_margin_hz', 'gain_margin', 'delay_ms', 'delay_xcorr_ms')
#: The fit error of the fixed-order rational fit above which ``seft identify`` warns that
#: the loop figures it prints (:data:`_IDENTIFY_FIGURES`, read on that fit) are not to be
#: trusted [-]: seft's own rig fits within 0.7 %, and the figures' documented tolerances
#: (docs: tutorials/identification) hold there; an actuator of another order fitted at
#: 6 % gave a crossover of 8.1 Hz for 13.6 Hz and a phase margin of 34.5 deg for 46. A run
#: whose plant model (its order chosen by the data) fits the force within it gets a note
#: instead: the design and the parameter file are read on that model.
FIT_WARNING = 0.02


#: The NRMS displacement error of an accurate test of the study's kind
#: (:data:`seft_ros.core.stability.ACCURATE_TEST`) [-].
ACCURATE_TEST = stability.ACCURATE_TEST


def predicted_error_warning(design: dict) -> str:
    """Why a design's own prediction of the study's test with ``model`` is not an accurate
    test, or ``''``.

    Parameters
    ----------
    design : dict
        A design's JSON (:meth:`~seft_ros.core.force_design.ForceLoopDesign.to_json`): its
        ``predicted_error`` ``[[alpha, NRMS x], ...]``, ``structure.specimen_hz`` and
        ``controller_z.dt``.

    Returns
    -------
    str
        The predicted errors against :data:`ACCURATE_TEST` and, for a specimen of fewer than
        ``1 / COARSE_SAMPLING`` samples a period, the sample period that gives it more; ''
        when every predicted error is within its bound (or none is predicted).
    """
    from seft_ros.core.force_design import COARSE_SAMPLING, shorter_sample_period_s
    predicted = [(float(a), float(e)) for a, e in design.get('predicted_error') or ()]

    if not any(e > stability.accurate_test_bound(a) for a, e in predicted):
        return ''
    text = ("the study's test with `model` on this loop is predicted at "
            + ' / '.join(f'{100 * e:.2g}' for _, e in predicted) + ' % NRMS x at alpha '
            + ' / '.join(f'{a:g}' for a, _ in predicted)
            + ', more than an accurate test (1 % up to alpha 1, 2 % beyond)')
    f_n = float((design.get('structure') or {}).get('specimen_hz') or 0.0)
    dt = float((design.get('controller_z') or {}).get('dt') or 0.0)
    if f_n > 0 and dt > 0 and f_n * dt > COARSE_SAMPLING:
        text += (f': the specimen ({f_n:.3g} Hz) has {1.0 / (f_n * dt):.3g} samples a period '
                 f'at dt {1e3 * dt:g} ms; identify and design again at a sample period of at '
                 f'most {1e3 * shorter_sample_period_s(f_n, dt):.2g} ms')
    return text


def identification_table(doc: dict) -> str:
    """What ``seft identify`` prints of its JSON document: the study's rig's figures with its
    known model's, then each rig's specimen and verdict (a structure's: per rig, with the
    figures of its force loop).
    """
    lines = []
    rigs = list(doc.get('rigs') or {'': doc})
    for rig in rigs:
        figures = doc['rigs'][rig] if 'rigs' in doc else doc
        runs = [r for r in doc['runs'] if r.get('rig', '') == rig]
        if rig:
            lines.append(f'rig {rig}:')
        if any(figures.get(key) is not None for key in _IDENTIFY_FIGURES):
            # which loop the figures are of (a lab's crossover of 57.8 Hz beside its known
            # model's 2.2 Hz, unlabelled, was read as the designed loop's; session 36)
            source = next((r['figures']['model'].get('source') for r in runs
                           if (r['figures'].get('model') or {}).get('source')), None)
            designed = any(r['figures'].get('plant') and r['figures'].get('design')
                           for r in runs)
            lines.append("the run's loop: its force controller on the run's fixed-order fit"
                         + (' (the designed loop is below)' if designed else '')
                         + (f'; known model: {source}' if source else ''))
        for key in _IDENTIFY_FIGURES:
            if figures.get(key) is not None:
                model = next((r['figures']['model'].get(key) for r in runs
                              if key in r['figures']), None)
                known = f'  (known model {model:.4g})' if model is not None else ''
                lines.append(f'{key:18s} {figures[key]:10.4g}{known}')
        for r in runs:
            fit = r['figures'].get('fit') or {}
            if (fit.get('fit_error') or 0.0) > FIT_WARNING:
                lines.append(_fit_warning(fit, r['kind'], r['figures'].get('plant')))
        specs = [(r['kind'], r['figures']['specimen']) for r in runs
                 if r['figures'].get('specimen')]
        if specs:
            keys = ('mass_kg', 'damping_N_s_per_m', 'stiffness_N_per_m')
            lines.append(f'{"specimen":18s} {"m [kg]":>10s} {"c [N s/m]":>11s} '
                         f'{"k [N/m]":>11s}')

            def row(label, values, note=''):
                return (f'  {label:16s} {values[keys[0]]:10.5g} {values[keys[1]]:11.5g} '
                        f'{values[keys[2]]:11.5g}{note}').rstrip()
            for kind, spec in specs:
                note = (f'   linear (residual {100 * spec["residual"]:.2g} %)'
                        if spec['linear'] else f'   {spec["verdict"]}')
                lines.append(row(f'{kind} run', spec, note))
            lines.append(row('rig model', specs[0][1]['model']))
            lines.append(row('declared', specs[0][1]['declared']))
            lines.extend(_specimen_mismatch(specs))
        for r in runs:
            plant, design = r['figures'].get('plant'), r['figures'].get('design')
            if plant and design:
                m = design['margins']
                gm = m['gain_margin']
                misfit = plant['nrms']['force_N']
                level = plant.get('uncertainty') or {}
                lines.append(f"{'plant model':18s} order {plant['order']}, delay "
                             f"{plant['delay_steps']} steps, force NRMS {100 * misfit:.2g} %"
                             + (f'; WARNING: above {100 * stability.MAX_PLANT_MISFIT:g} %, '
                                'a nonlinear actuator (friction, valve flow): the guard gives '
                                'its runs no stability verdict'
                                if misfit > stability.MAX_PLANT_MISFIT else '')
                             + (f"; identified up to {level['peak_force_N']:.3g} N and "
                                f"{level['peak_velocity_m_s']:.3g} m/s (beyond "
                                f'{stability.MAX_LEVEL_EXTRAPOLATION:g} times either, a '
                                'stability verdict needs a fit within '
                                f'{100 * stability.LEVEL_MISFIT:g} %)'
                                if level.get('peak_velocity_m_s') else ''))
                if plant.get('polarity', 1) < 0:
                    lines.append(f"{'':18s} WARNING: its force answers a positive valve step "
                                 "with a negative force: the valve's or the load cell's "
                                 'polarity is reversed (a force controller of positive gain '
                                 'drives the loop away, whatever its margins read); fix the '
                                 'sign at the rig or in its plant model, then identify again')
                lines.append(f"{'designed loop':18s} crossover {m['crossover_hz']:.1f} Hz, phase "
                             f"margin {m['phase_margin_deg']:.0f} deg, gain margin "
                             + ('inf' if gm is None else f'{gm:.2f}')
                             + f", inverse {design['loop_delay_steps']} steps; targets "
                             + ('met' if design['met'] else 'NOT met: ' + '; '.join(
                                 design['notes'])))
                for warning in ([predicted_error_warning(design)]
                                + list(design.get('warnings') or ())):
                    if warning:
                        lines.append(f"{'':18s} WARNING: {warning}")
                miss = design.get('inverse_band_error')
                if miss is not None and not miss <= MAX_BAND_ERROR:
                    lines.append(f"{'':18s} WARNING: no force-loop inverse of 2-30 steps "
                                 'follows this loop (the best misses it by '
                                 + ('an unbounded amount' if not np.isfinite(miss) else
                                    f'{100 * miss:.0f} %')
                                 + ' up to 25 Hz): the `model` and `adaptive` compensators '
                                 'will refuse these settings (`none`, `polynomial` and '
                                 '`ats` need no inverse)')
        # what the parameter file does not get, and why (rig_identification's notes)
        written = (figures.get('parameters') if 'rigs' in doc else doc.get('parameters')) or {}
        plant_note, design_note = str(written.get('_plant', '')), str(written.get('_design', ''))
        if plant_note.startswith('not identified'):
            lines.append(f"{'plant model':18s} not identified (it needs the specimen fit above): "
                         'none for the parameter file, which --params then refuses to write')
        if design_note.startswith('NOT written: '):
            lines.append(f"{'':18s} designed controller NOT written to the parameter file: "
                         + design_note[len('NOT written: '):])
    return '\n'.join(lines)


def _fit_warning(fit: dict, kind: str, plant: dict | None) -> str:
    """The line on loop figures read on a fixed-order rational fit that misses the run's
    response by more than :data:`FIT_WARNING`: a note when the run's plant model (its order
    chosen by the data) fits the force within that bound, since the designed loop and the
    parameter file are read on it; a warning otherwise."""
    head = (f"the figures above are read on a rational fit of orders {tuple(fit['orders'])} "
            f"that misses the {kind} run's response by {100 * fit['fit_error']:.1f} % (above "
            f'{100 * FIT_WARNING:g} %)')
    if not plant:
        return f'WARNING: {head}: identify again with --orders NB NA'
    misfit = plant['nrms']['force_N']
    if misfit <= FIT_WARNING:
        return (f"note: {head}; the plant model below (order {plant['order']}) fits the "
                f'force to {100 * misfit:.2g} %, and the designed loop and the parameter file '
                'are read on it (--orders NB NA reads the figures above closer)')
    return (f'WARNING: {head}, and the plant model below misses the force by '
            f'{100 * misfit:.2g} %: no linear model of this order fits the actuator at this '
            'level (friction, valve flow); trust neither the figures above nor the designed '
            'loop far')
