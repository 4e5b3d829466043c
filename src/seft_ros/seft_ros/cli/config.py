"""Run configuration files and command-line overrides (no rclpy).

A configuration is a ROS 2 parameter file (``/**: ros__parameters: {...}``, the format of
``--params-file``) or a plain mapping of the same parameters. For ``seft run`` and
``seft simulate`` only, ``alpha`` and ``predictor`` may be lists: one run per combination
(predictors outer, alphas inner).
"""

from pathlib import Path
from typing import Any

import yaml

from seft_msgs_py import parameters
from seft_msgs_py.errors import InputError, ParameterError

__all__ = ['load_config', 'expand_runs', 'write_params_file']


def load_config(path) -> dict[str, Any]:
    """Read a configuration file into ``{name: value}`` (not yet validated).

    Raises
    ------
    InputError
        Missing file, invalid YAML, or not a mapping of parameters.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f'{path}: no such configuration file')
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f': line {mark.line + 1}' if mark is not None else ''
        raise InputError(f'{path}{where}: invalid YAML ({getattr(exc, "problem", exc)})') \
            from None
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
    known = parameters.defaults()
    for key in data:
        if key not in known:
            raise InputError(f'{path}: unknown parameter {key!r}')
    return data


def expand_runs(config: dict[str, Any], *, where: str = '') -> list[dict[str, Any]]:
    """Validate a configuration and expand lists of ``record``, ``predictor`` and ``alpha``
    into one parameter set per combination (in that order of nesting).

    Raises
    ------
    ParameterError
        A value out of range (the message names the parameter and, if given, `where`).
    """
    def values_of(name):
        value = config.get(name, parameters.spec(name).default)
        values = list(value) if isinstance(value, (list, tuple)) else [value]
        if not values:
            raise ParameterError(f'{where + ": " if where else ""}parameter {name}: expected '
                                 'at least one value')
        return values

    alphas, predictors, records = (values_of(n) for n in ('alpha', 'predictor', 'record'))
    runs = []
    for record in records:
        for predictor in predictors:
            for alpha in alphas:
                values = dict(config, alpha=alpha, predictor=predictor, record=record)
                runs.append(parameters.resolve(values, where=where))
    return runs


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
