"""Run configuration files and command-line overrides (no rclpy).

A configuration is a ROS 2 parameter file (``/**: ros__parameters: {...}``, the format of
``--params-file``) or a plain mapping of the same parameters. For ``seft run`` and
``seft simulate`` only, ``alpha`` and ``predictor`` may be lists: one run per combination
(predictors outer, alphas inner).

A plain mapping may also hold a ``structure`` section (the whole structure, its physical
degrees of freedom on rigs: :mod:`seft_ros.core.structure`) and a ``rigs`` section (each rig's
own parameters: its rig model, specimen, controller). They become the ``structure`` parameter
(the structure's JSON, with the rigs' sections); each run is then checked against them
(:func:`expand_runs`). A structure that is the reference study's test (one rig, only a rigid
mass on it) runs as that test, bit for bit, with ``alpha`` = the rigid mass over the
specimen's.

A parameter file layered over a configuration (``--params FILE``, :func:`load_config` with
``layer=True``) may hold a ``rigs`` section without a structure (``seft identify``'s file of a
structure's rigs): each of its rig sections is merged into the configuration's section of
that rig (:func:`layer_rigs`), its values over the configuration's. A rig section holds
only a rig's parameters, never one of the whole test
(``seft_msgs_py.parameters.TEST_PARAMETERS``).
"""

from dataclasses import replace
import json
import os
from pathlib import Path
import re
from typing import Any, Callable

import yaml

from seft_msgs_py import parameters
from seft_msgs_py.errors import InputError, ParameterError
from seft_msgs_py.parameters import identification_run

__all__ = ['load_config', 'expand_runs', 'write_params_file', 'ConfigLoader', 'layer_rigs',
           'RIGS', 'mapping_values', 'read_yaml']

#: The key of :func:`load_config`'s result that holds a layered file's ``rigs`` section.
RIGS = 'rigs'


class ConfigLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that reads floats as YAML 1.2 does: ``2.11e5`` and ``1e-12`` are
    numbers (YAML 1.1, PyYAML's default, wants a dot and a signed exponent and reads them as
    strings: a stiffness written ``2.11e5`` would be refused as text)."""


ConfigLoader.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                  |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                  |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                  |[-+]?\.(?:inf|Inf|INF)
                  |\.(?:nan|NaN|NAN))$""", re.X),
    list('-+0123456789.'))


def load_config(path, *, layer: bool = False) -> dict[str, Any]:
    """Read a configuration file into ``{name: value}`` (not yet validated).

    Parameters
    ----------
    path : str or Path
    layer : bool
        The file is layered over a configuration (``--params``): a ``rigs`` section without
        a ``structure`` section is returned under :data:`RIGS` (rig name -> its parameters,
        checked against the schema), for :func:`layer_rigs`.

    Raises
    ------
    InputError
        Missing file, invalid YAML, not a mapping of parameters, or a ``rigs`` section
        without a structure (`layer` False), not a mapping of rig names to mappings, or
        that sets a parameter of the whole test.
    ParameterError
        A rig section's value out of range (`layer`).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f'{path}: no such configuration file')
    data = read_yaml(path)
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError(f'{path}: expected a mapping of parameters')
    if len(data) == 1:
        (key, value), = data.items()
        if isinstance(value, dict) and 'ros__parameters' in value:
            data = value['ros__parameters']
            if not isinstance(data, dict):
                raise InputError(f'{path}: {key}.ros__parameters: expected a mapping')
    data = {k: v for k, v in data.items() if k != 'use_sim_time'}
    data = mapping_values(data, base=path.parent, where=str(path))
    structure, rigs = data.pop('structure', None), data.pop('rigs', None)
    if isinstance(rigs, dict):
        rigs = {r: (mapping_values(v, base=path.parent, where=f'{path}: rigs.{r}')
                    if isinstance(v, dict) else v) for r, v in rigs.items()}
    if isinstance(structure, dict):
        from seft_ros.core.structure import parse_structure  # numpy, scipy: only if needed
        data['structure'] = parse_structure(structure, rigs=rigs, where=f'{path}: structure',
                                            base=path.parent).to_json()
    elif rigs is not None and not layer:
        raise InputError(f'{path}: rigs: a rigs section needs a structure section (the '
                         'structure names the rig of each physical degree of freedom)')
    elif structure is not None:
        data['structure'] = structure
    known = parameters.defaults()
    for key in data:
        if key not in known:
            raise InputError(f'{path}: {parameters.unknown_parameter(key)}')
    if rigs is not None and not isinstance(structure, dict):
        data[RIGS] = _rig_sections(rigs, where=f'{path}: rigs')
    return data


def read_yaml(path: Path) -> Any:
    """The YAML document of the file `path` (read with :class:`ConfigLoader`).

    Raises
    ------
    InputError
        The file is not UTF-8 text, or not valid YAML (the message names the file, and the
        line when the parser knows it).
    """
    try:
        text = path.read_text(encoding='utf-8')
    except UnicodeDecodeError as exc:
        raise InputError(f'{path}: not UTF-8 text (byte {exc.start}); expected a YAML file') \
            from None
    try:
        return yaml.load(text, Loader=ConfigLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f': line {mark.line + 1}' if mark is not None else ''
        raise InputError(f'{path}{where}: invalid YAML ({getattr(exc, "problem", exc)})') \
            from None


def mapping_values(values: dict[str, Any], *, base: Path | None = None,
                   where: str = '') -> dict[str, Any]:
    """`values` with each mapping parameter (``seft_msgs_py.parameters.MAPPING_PARAMETERS``:
    ``plant_model``, ``force_controller_tf``) as the JSON text the nodes take.

    A value may be the mapping itself, its JSON, ``'none'``, or the path of a YAML file that
    holds the mapping (relative to `base`, the configuration's folder).

    Raises
    ------
    InputError
        A file that does not exist, is not YAML or does not hold a mapping; a value that is
        none of the above (the message names `where` and the parameter).
    """
    out = dict(values)
    for name in parameters.MAPPING_PARAMETERS:
        if name not in out:
            continue
        value = out[name]
        label = f'{where}: {name}' if where else f'parameter {name}'
        if isinstance(value, dict):
            out[name] = json.dumps(value, sort_keys=True, separators=(',', ':'))
        elif isinstance(value, str) and value.strip() not in ('none', '') \
                and not value.lstrip().startswith('{'):
            file = Path(value).expanduser()
            if base is not None and not file.is_absolute():
                file = base / file
            if not file.is_file():
                raise InputError(f'{label}: {value}: no such file (a mapping, its JSON, or the '
                                 'path of a YAML file holding it)')
            doc = read_yaml(file)
            if isinstance(doc, dict) and list(doc) == [name] and isinstance(doc[name], dict):
                doc = doc[name]                     # a file with the parameter's own key
            if not isinstance(doc, dict):
                raise InputError(f'{file}: expected a mapping ({name})')
            out[name] = json.dumps(doc, sort_keys=True, separators=(',', ':'))
            _remember_file(out[name], file)
        elif not isinstance(value, str):
            raise InputError(f'{label}: expected a mapping, its JSON or a YAML file path, got '
                             f'{value!r}')
    return out


#: The files the mapping parameters were read from, by the JSON text read
#: (:func:`mapping_file`; the latest few).
_MAPPING_FILES: dict[str, Path] = {}


def _remember_file(text: str, file: Path) -> None:
    _MAPPING_FILES.pop(text, None)
    if len(_MAPPING_FILES) >= 32:
        _MAPPING_FILES.pop(next(iter(_MAPPING_FILES)))
    _MAPPING_FILES[text] = file


def mapping_file(text) -> Path | None:
    """The YAML file a mapping parameter's JSON `text` was read from by
    :func:`mapping_values` in this process, or None (given inline, on the command line, or
    not read here)."""
    return _MAPPING_FILES.get(text) if isinstance(text, str) else None


def _rig_sections(rigs, *, where: str) -> dict[str, dict[str, Any]]:
    """A layered file's ``rigs`` section, checked: rig -> {parameter: value}."""
    if not isinstance(rigs, dict):
        raise InputError(f'{where}: expected a mapping of rig names to their parameters, got '
                         f'{rigs!r}')
    known = parameters.defaults()
    out = {}
    for rig, values in rigs.items():
        if not isinstance(values, dict):
            raise InputError(f'{where}.{rig}: expected a mapping of parameters, got {values!r}')
        section = {}
        for name, value in values.items():
            if name not in known:
                raise InputError(f'{where}.{rig}: {parameters.unknown_parameter(name)}')
            if name in parameters.TEST_PARAMETERS:
                raise InputError(f'{where}.{rig}.{name}: a parameter of the whole test, not of '
                                 'one rig; set it for all')
            section[name] = parameters.validate_value(name, value, where=f'{where}.{rig}')
        out[str(rig)] = section
    return out


def layer_rigs(values: dict[str, Any], sections: dict[str, dict[str, Any]], *,
               where: str) -> dict[str, Any]:
    """Merge rig sections over the rigs sections of a configuration's structure.

    Parameters
    ----------
    values : dict
        A configuration (:func:`load_config`) with a ``structure``.
    sections : dict of str to dict
        Rig name -> parameters (a layered file's :data:`RIGS`); each value replaces the
        configuration's for that rig.
    where : str
        The layered file, for the error messages.

    Returns
    -------
    dict
        `values` with the structure's rigs sections updated.

    Raises
    ------
    InputError
        The configuration has no structure, or its structure has no rig of that name (the
        message names `where`, the rig and the structure's rigs).
    """
    structure = values.get('structure', 'none')
    if structure in ('none', '', None):
        raise InputError(f'{where}: rigs: a rigs section needs a structure, and the '
                         'configuration has none (layer it over the configuration of the '
                         'structure: seft run CONFIG --params FILE)')
    from types import MappingProxyType

    from seft_ros.core.structure import Structure
    s = Structure.from_json(structure)
    for rig in sections:
        if rig not in s.rigs:
            raise InputError(f'{where}: rigs.{rig}: the structure has no rig {rig!r} (its '
                             f'rigs: {", ".join(s.rigs)})')
    rigs = {r: MappingProxyType(dict(v, **sections.get(r, {}))) for r, v in s.rigs.items()}
    return dict(values, structure=replace(s, rigs=MappingProxyType(rigs)).to_json())


def same_value(name: str, value: Any) -> Any:
    """What makes two values of a swept parameter the same run: an alpha's number, a
    record's file (``rec/a.AT2`` and ``./rec/a.AT2`` are one record), else the value."""
    if name == 'alpha':
        try:
            return float(value)
        except (TypeError, ValueError):
            return value
    if name == 'record' and str(value) != 'default':
        return os.path.realpath(str(value))
    return value


def repeated(name: str, values: list) -> Any:
    """The first value of `values` that is the same run as an earlier one, else None."""
    seen = set()
    for v in values:
        key = same_value(name, v)
        if key in seen:
            return v
        seen.add(key)
    return None


def expand_runs(config: dict[str, Any], *, where: str = '',
                notes: list[str] | None = None,
                origin: dict[str, str] | None = None) -> list[dict[str, Any]]:
    """Validate a configuration and expand lists of ``record``, ``predictor`` and ``alpha``
    into one parameter set per combination (in that order of nesting).

    A bad value is named as its source's: `origin` (parameter name to the file or
    ``'command line'`` that gave it), else `where` (a ``plant_model`` of a ``--params`` file
    was named as the configuration's; a new user, session 36).

    A rig whose specimen is declared to yield gets the settings of a yielding member where
    the configuration does not set them
    (:func:`~seft_ros.core.specimen_settings.follow_specimen`); the lines saying which are
    appended to `notes` (each once).

    Raises
    ------
    ParameterError
        A value out of range (the message names the parameter and, if given, `where`).
    """
    from seft_ros.core.specimen_settings import follow_specimen
    origin = origin or {}

    def at(name: str) -> str:
        """The prefix of a message on parameter `name`: its source's."""
        source = origin.get(name, where)
        return f'{source}: ' if source else ''

    def values_of(name):
        value = config.get(name, parameters.spec(name).default)
        values = list(value) if isinstance(value, (list, tuple)) else [value]
        if not values:
            raise ParameterError(f'{at(name)}parameter {name}: expected at least one value')
        return values

    alphas, predictors, records = (values_of(n) for n in ('alpha', 'predictor', 'record'))
    for name, values in (('alpha', alphas), ('predictor', predictors), ('record', records)):
        twice = repeated(name, values)
        if twice is not None:
            raise ParameterError(f'{at(name)}parameter {name}: {twice!r} twice: the same run '
                                 'twice; expected each value once')
    runs = []
    for record in records:
        for predictor in predictors:
            for alpha in alphas:
                values = dict(config, alpha=alpha, predictor=predictor, record=record)
                params, chosen = follow_specimen(config, parameters.resolve(
                    values, where=where, origin=origin))
                amplitude, scale = float(params['amplitude_N']), float(params['scale_factor'])
                if amplitude > 0 and scale != 1.0:
                    # amplitude_N wins in ground_motion.prepare: the scale would be ignored
                    raise ParameterError(
                        f'{at("scale_factor")}parameter scale_factor={scale!r}: used only '
                        f'with amplitude_N 0 (amplitude_N={amplitude:g} scales the record to '
                        'that peak force); set amplitude_N to 0, or leave scale_factor at 1')
                if notes is not None:
                    notes.extend(n for n in chosen if n not in notes)
                runs.append(_with_structure(params, where, at))
    return runs


def _with_structure(params: dict[str, Any], where: str,
                    at: Callable[[str], str]) -> dict[str, Any]:
    """A run with a structure, checked against its rigs
    (:func:`~seft_ros.core.structure.test_setup`); the study's test if it reduces to it
    (:func:`~seft_ros.core.structure.reduces_to_study`); an identification run (an
    ``excitation``) of any other structure tests its rigs alone, each in its namespace
    (:func:`~seft_ros.core.excitation.rigs_alone`).

    Raises
    ------
    ParameterError
        The structure disagrees with a rig's parameters, or a rig section sets a parameter of
        the whole test (the message names the field and `where`; a value of the whole test,
        its source, ``at(name)``, the prefix of a message on parameter `name`).
    """
    if params.get('structure', 'none') in ('none', '', None):
        _check_mappings(params, at)
        _check_watchdog(params, at('watchdog_timeout_s'))
        _check_controller_address(params, at('udp_controller_address'))
        return params
    from seft_ros.core.structure import reduces_to_study, study_parameters, test_setup
    try:
        setup = test_setup(params)
        for rig, rp in setup.rig_params.items():
            _check_mappings(rp, lambda name, rig=rig: f'rig {rig}: ')
            _check_watchdog(rp, f'rig {rig}: ')
            _check_controller_address(rp, f'rig {rig}: ')
        if reduces_to_study(setup.substructures):
            return study_parameters(params, setup.substructures)
    except ParameterError as exc:
        raise ParameterError(f'{where}: {exc}' if where else str(exc)) from None
    if float(params.get('alpha', 0.0)) != 0.0:
        # the structure's masses are its mass ratios: an alpha would be ignored
        raise ParameterError(f'{at("alpha")}parameter alpha={params["alpha"]!r}: with a '
                             "structure the computational masses are the structure's; leave "
                             'alpha at 0')
    if identification_run(params):
        from seft_ros.core.excitation import rigs_alone
        try:
            return rigs_alone(params)
        except ParameterError as exc:
            raise ParameterError(f'{where}: {exc}' if where else str(exc)) from None
    return params


#: The shortest real-time watchdog, in sample periods: an input is due every dt, and a
#: sample lost on the way (the graph carries on with the latest one) leaves 2 dt of
#: silence; a third dt is the room for a late sample's scheduling jitter. A shorter limit
#: ends the run at the first lost or late sample (below dt: at the first step).
_WATCHDOG_MIN_STEPS = 3


def _check_watchdog(params: dict[str, Any], prefix: str) -> None:
    """Refuse a real-time watchdog shorter than :data:`_WATCHDOG_MIN_STEPS` sample periods (a
    lockstep run has none: its nodes wait for each other).

    Raises
    ------
    ParameterError
        The message (after `prefix`: ``'<source>: '`` or empty) names the parameter, the
        bound and the run's dt.
    """
    if params.get('mode') != 'realtime':
        return
    limit, dt = float(params['watchdog_timeout_s']), float(params['dt'])
    if limit < _WATCHDOG_MIN_STEPS * dt * (1.0 - 1e-9):
        raise ParameterError(
            f'{prefix}parameter watchdog_timeout_s={limit:g}: expected '
            f'at least {_WATCHDOG_MIN_STEPS} sample periods, {_WATCHDOG_MIN_STEPS * dt:g} s at '
            f'dt={dt:g} s (an input is due every dt: a shorter watchdog ends the run at the '
            'first lost or late sample)')


def _check_controller_address(params: dict[str, Any], prefix: str) -> None:
    """A real-time UDP bridge's ``udp_controller_address`` is ``host:port`` with a host that
    resolves, checked before anything starts (it was refused by the rig node 7-8 s into the
    start, the other ``udp_*`` values in 1 s).

    Raises
    ------
    ParameterError
        As :func:`~seft_plant_sim.udp_bridge.resolve_address`, after `prefix` (``'<source>: '``
        or empty).
    """
    if params.get('mode') != 'realtime' or params.get('rig_interface') != 'udp_bridge':
        return
    from seft_plant_sim.udp_bridge import resolve_address
    try:
        resolve_address(params['udp_controller_address'])
    except ParameterError as exc:
        raise ParameterError(f'{prefix}{exc}') from None


def _check_mappings(params: dict[str, Any], at: Callable[[str], str]) -> None:
    """Parse a rig's ``plant_model``, ``rig_plant_model`` and ``force_controller_tf`` now (a
    bad field is refused before anything runs).

    Raises
    ------
    ParameterError
        The message (after ``at(name)``, the prefix naming parameter `name`'s source) names
        the parameter and the field; a ``rig_plant_model`` on a rig other than
        ``state_space`` (no other rig reads it).
    """
    from seft_msgs_py.plant import parse_plant
    from seft_ros.core.force_loop import has_plant_model
    rig_plant = params.get('rig_plant_model', 'none') not in (None, '', 'none')
    if rig_plant and params.get('rig_model') != 'state_space':
        raise ParameterError(f"{at('rig_plant_model')}parameter rig_plant_model: the plant a "
                             "rig_model "
                             f"'state_space' steps, and this rig is "
                             f"{params.get('rig_model')!r} (its physics is its own): set "
                             "rig_model state_space, or rig_plant_model none")
    for name, given in (('plant_model', has_plant_model(params)),
                        ('rig_plant_model', rig_plant)):
        if not given:
            continue
        file = mapping_file(params[name])
        try:
            # a model read from a file of its own: the error names that file (it named the
            # configuration that points to it; a new user, session 38)
            parse_plant(params[name], dt=float(params['dt']),
                        where=f'{file}: {name}' if file else f'parameter {name}')
        except ParameterError as exc:
            raise ParameterError(f'{exc}' if file else f'{at(name)}{exc}') from None
    if params.get('force_controller') == 'transfer_function':
        from seft_ros.core.controller import ControllerTF
        try:
            ControllerTF.from_parameter(params.get('force_controller_tf', 'none'),
                                        dt=float(params['dt']))
        except ParameterError as exc:
            raise ParameterError(f'{at("force_controller_tf")}{exc}') from None


def write_params_file(params: dict[str, Any], path) -> Path:
    """Write `params` as a ROS 2 parameter file for every node (``/**``).

    ``use_sim_time`` is on in lockstep (ROS time is the rig's simulated clock) and off in real
    time (the wall clock is the time; no node then listens to ``/clock`` but the ground-motion
    publisher).
    """
    path = Path(path)
    sim_time = params.get('mode', 'lockstep') != 'realtime'
    body = {'/**': {'ros__parameters': dict(params, use_sim_time=sim_time)}}
    path.write_text('# seft run parameters (ROS 2 --params-file format)\n'
                    + yaml.safe_dump(body, sort_keys=True))
    return path
