"""The registry of simulated rig models, chosen by the ``rig_model`` parameter.

A hardware DAQ/servo bridge would register here under its own name: the test loop only sees
the :class:`~seft_msgs_py.interface.Rig` protocol. Each simulated rig takes its specimen from
``specimen_model`` (:data:`~seft_plant_sim.specimen.SPECIMEN_MODELS`: 'linear', stepped
exactly, or the hysteretic 'bouc_wen', stepped with RK4 substeps).
"""

from typing import Callable, Mapping

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import Rig
from seft_plant_sim.actuator import ActuatorRig
from seft_plant_sim.delay_rig import DelayRig
from seft_plant_sim.lti_rig import StateSpaceRig
from seft_plant_sim.servohydraulic import ServoHydraulicRig

__all__ = ['RIG_MODELS', 'make_rig']

#: ``rig_model`` name -> factory taking the flat parameter mapping.
RIG_MODELS: dict[str, Callable[..., Rig]] = {
    'delay': DelayRig.from_parameters,
    'servohydraulic': ServoHydraulicRig.from_parameters,
    'state_space': StateSpaceRig.from_parameters,
    'actuator': ActuatorRig.from_parameters,
}


def make_rig(params: Mapping, **options) -> Rig:
    """Build the rig named by ``params['rig_model']`` from the flat parameter mapping.

    Parameters
    ----------
    params : mapping
        The resolved experiment parameters (``rig_model``, ``dt``, specimen with
        ``specimen_model``, noise, limits and the model's own keys).
    **options
        Passed to the model's ``from_parameters`` (``rk4_substeps``: Runge-Kutta substeps
        per step of a hysteretic specimen).

    Returns
    -------
    Rig

    Raises
    ------
    ParameterError
        If ``rig_model`` is missing or not a registered name, or a model parameter is out of
        range.
    """
    name = params.get('rig_model')
    try:
        factory = RIG_MODELS[name]
    except (KeyError, TypeError):
        expected = ', '.join(repr(n) for n in RIG_MODELS)
        raise ParameterError(f'parameter rig_model={name!r}: expected one of {expected}') \
            from None
    return factory(params, **options)
