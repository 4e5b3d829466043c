"""Which plant a rig's force loop has: the one object every consumer takes.

The force controller's design, the compensators' force-loop inverse and priors, the stability
map, the pre-run guard and its robustness margin, and ``seft identify``'s comparison reason
with the force loop's plant (:class:`~seft_msgs_py.plant.PlantModel`). This module says which
one a run has (:func:`force_loop_plant`):

1. the ``plant_model`` parameter, when set: a lab's own model or the one ``seft identify``
   wrote from the lab's bags (its specimen is the one it was identified with);
2. otherwise, on the ``servohydraulic`` rig, seft's model of that rig
   (:class:`seft_plant_sim.servohydraulic.ServoHydraulicPlant`) with the specimen of the run
   (the rig's, or the compensators' declared model of it);
3. any other valve-driven rig has no model: :class:`NoPlantModelError` says to identify it.

Imports nothing of ROS; ``seft_plant_sim`` only for seft's own rig model (it need not be
installed on a lab's controller host that has a ``plant_model``).
"""

import functools
from typing import Mapping

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.parameters import mapping_value, rig_plant_parameter, valve_commanded
from seft_msgs_py.plant import PlantModel, parse_plant

__all__ = ['NoPlantModelError', 'has_plant_model', 'force_loop_plant', 'compensator_plant',
           'plant_text', 'rig_plant']


class NoPlantModelError(ParameterError):
    """A valve-driven rig without a model of its force loop (no ``plant_model``)."""


def plant_text(params: Mapping) -> str | None:
    """The ``plant_model`` parameter's JSON, or None when it is not set ('none')."""
    text = params.get('plant_model', 'none')
    return None if text in (None, '', 'none') else str(text)


def has_plant_model(params: Mapping) -> bool:
    """Whether the run gives its force loop's plant as data (``plant_model``)."""
    return plant_text(params) is not None


@functools.lru_cache(maxsize=16)
def _parsed(text: str, dt: float, where: str = 'parameter plant_model') -> PlantModel:
    return parse_plant(text, dt=dt, where=where)


def rig_plant(params: Mapping) -> tuple[str, PlantModel] | None:
    """The plant a ``state_space`` rig steps and the parameter that gives it
    (:func:`~seft_msgs_py.parameters.rig_plant_parameter`: ``rig_plant_model``, else
    ``plant_model``).

    Parameters
    ----------
    params : mapping
        A rig's resolved parameters (``rig_model``, ``dt``).

    Returns
    -------
    tuple of (str, PlantModel) or None
        None for another rig, or a ``state_space`` rig with neither model.

    Raises
    ------
    ParameterError
        A model that does not parse (the message names the parameter and the field).
    """
    if params.get('rig_model') != 'state_space':
        return None
    name = rig_plant_parameter(params)
    if name is None:
        return None
    text = params[name]
    if not isinstance(text, str):
        import json
        text = json.dumps(mapping_value(text, where=f'parameter {name}',
                                        expected='a plant model mapping'))
    return name, _parsed(text, float(params['dt']), f'parameter {name}')


def force_loop_plant(params: Mapping, *, predictor: bool = False,
                     stiffness_ratio: float | None = None) -> PlantModel:
    """The plant of a run's force loop (see the module notes).

    Parameters
    ----------
    params : mapping
        A rig's resolved parameters.
    predictor : bool
        seft's rig model with the compensators' declared specimen (``predictor_*``, 0: the
        rig's) and I/O latency (``predictor_io_latency_s``, 0: the rig's) instead of the
        rig's own: what the compensators model. A ``plant_model`` is the same either way (its
        specimen is the one it was identified with).
    stiffness_ratio : float, optional
        seft's rig model with the specimen's stiffness scaled by this (the robustness
        margin's and a yielding member's frozen tangent).

    Returns
    -------
    PlantModel

    Raises
    ------
    NoPlantModelError
        A valve-driven rig without ``plant_model`` that is not seft's servohydraulic rig, or
        a stiffness ratio for a model of data (its specimen is inside it).
    ParameterError
        A ``plant_model`` that does not parse (the message names the field), or
        ``seft_plant_sim`` missing for seft's own rig model.
    """
    dt = float(params['dt'])
    text = plant_text(params)
    if text is not None:
        if stiffness_ratio is not None and stiffness_ratio != 1.0:
            raise NoPlantModelError('plant_model: a model of data has its specimen inside it; '
                                    'its specimen stiffness cannot be varied')
        if predictor and float(params.get('predictor_io_latency_s', 0.0) or 0.0) > 0:
            raise ParameterError("parameter predictor_io_latency_s applies to seft's "
                                 'servohydraulic rig model; with plant_model the latency is the '
                                 "model's (io_delay_s): set it to 0")
        return _parsed(text, dt)
    rig = params.get('rig_model', 'servohydraulic')
    if rig != 'servohydraulic':
        kind = 'takes the reference force' if not valve_commanded(rig) else \
            'has no model of its force loop'
        raise NoPlantModelError(
            f'rig_model {rig!r} {kind}: identify it (an open-loop run with excitation_input '
            'valve_command, then seft identify RUN --params FILE) or give its plant_model')
    try:
        from seft_plant_sim.servohydraulic import ServoHydraulicParams, ServoHydraulicPlant
        from seft_plant_sim.specimen import LinearSpecimen
    except ImportError as exc:
        raise ParameterError(
            "the force loop of rig_model servohydraulic: seft's model of that rig comes from "
            f'seft_plant_sim, which cannot be imported here ({exc}); install it, or give the '
            "rig's plant_model") from None
    if predictor:
        from seft_ros.core.predictors import model_parameters, model_rig
        mp = model_parameters(params)
        hp = model_rig(params)
        spec = LinearSpecimen(mp['mass_kg'], mp['damping_N_s_per_m'], mp['stiffness_N_per_m'])
    else:
        hp = ServoHydraulicParams.from_parameters(params)
        spec = LinearSpecimen.from_parameters(params)
    if stiffness_ratio is not None:
        spec = LinearSpecimen(spec.mass_kg, spec.damping_N_s_per_m,
                              spec.stiffness_N_per_m * float(stiffness_ratio))
    return ServoHydraulicPlant(hp, spec, dt)


def compensator_plant(params: Mapping) -> PlantModel:
    """The plant the compensators model: :func:`force_loop_plant` with ``predictor``."""
    return force_loop_plant(params, predictor=True)
