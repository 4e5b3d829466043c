"""The rig calibration: in which units the reference study's force controller is read.

The reference study gives its loop-shaping force controller as
``C_f(s) = 37/(s^2 + 17.14 s + 4002)`` (paper Eq. 3.1) without units, and it does not give
the servo valve's rating. Only the loop gain ``C_f * H_fu`` is calibrated (the 12 Hz
crossover, paper Fig. 3c), and ``H_fu`` is proportional to ``A k_q``: the crossover fixes
the product of the controller gain and the valve flow gain ``k_q``, hence the valve's
velocity at full command ``k_q u_max / A``, whatever the piston area, oil volume or bulk
modulus.

Two readings, one force loop (every calibration number is the same in both):

``'us_customary'`` (default)
    Eq. 3.1 in V/lbf, as the lab's ratings are US customary (24.5 kN = 5.5 kip actuator,
    22.2 kN = 5 kip load cell, 152 mm = 6 in stroke): ``C_f`` in SI is
    ``(37 / 4.4482216152605) V/N``, the valve flow gain is 4.448 times larger
    (2.358e-4 m^3/(s V)) and the actuator passes 2.0 m/s at 10 V (within the MTS 252 valve
    family's flow range). The reference study's own test (Kobe at 1000 N, time scale 0.5)
    then runs compensated at every alpha up to 2 without valve saturation.
``'si'``
    Eq. 3.1 in V/N: ``k_q = 5.3e-5 m^3/(s V)``, 0.45 m/s at 10 V; the valve saturates in a
    compensated run of that test at alpha >= 1 (its reference response needs 0.60 m/s).

Imports nothing of ROS; the controller, the rig model and the pre-run checks read the
calibration from the same parameters through :func:`controller_gain_V_per_N` and
:func:`valve_flow_gain_m3_per_s_V`.
"""

from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

from seft_msgs_py.errors import ParameterError

__all__ = ['LBF_N', 'EQ31_GAIN', 'RigCalibration', 'CALIBRATIONS', 'DEFAULT_CALIBRATION',
           'calibration', 'controller_gain_V_per_N', 'valve_flow_gain_m3_per_s_V']

#: One pound-force [N] (exact by definition: 0.45359237 kg x 9.80665 m/s^2).
LBF_N = 4.4482216152605
#: Numerator of paper Eq. 3.1, in volts per unit of force of the reading.
EQ31_GAIN = 37.0
#: Valve flow gain of the 'si' reading [m^3/(s V)] (calibrated: with A = 1.18e-3 m^2 and
#: Eq. 3.1 in V/N it puts the force loop's crossover at 12 Hz, paper Fig. 3c).
_KQ_SI = 5.3e-5


@dataclass(frozen=True)
class RigCalibration:
    """One reading of paper Eq. 3.1 with the valve flow gain that keeps the loop calibrated.

    Attributes
    ----------
    name : str
        ``'us_customary'`` or ``'si'``.
    force_unit_N : float > 0
        The force unit Eq. 3.1 is read in [N] (1 lbf or 1 N).
    controller_gain_V_per_N : float > 0
        Numerator of ``C_f(s)`` in SI [V/N]: ``37 / force_unit_N``.
    valve_flow_gain_m3_per_s_V : float > 0
        Valve flow gain k_q [m^3/(s V)]: ``5.3e-5 * force_unit_N``, so that the loop gain
        ``C_f k_q`` is the same in every reading.
    """

    name: str
    force_unit_N: float

    @property
    def controller_gain_V_per_N(self) -> float:
        return EQ31_GAIN / self.force_unit_N

    @property
    def valve_flow_gain_m3_per_s_V(self) -> float:
        return _KQ_SI * self.force_unit_N


#: The named readings, by the values of the ``rig_calibration`` parameter.
CALIBRATIONS: Mapping[str, RigCalibration] = MappingProxyType({
    'us_customary': RigCalibration('us_customary', LBF_N),
    'si': RigCalibration('si', 1.0),
})
#: The reading used when a parameter mapping has no ``rig_calibration``.
DEFAULT_CALIBRATION = 'us_customary'


def calibration(params: Mapping) -> RigCalibration:
    """Return the :class:`RigCalibration` named by ``params['rig_calibration']``.

    Raises
    ------
    ParameterError
        If the name is not one of :data:`CALIBRATIONS`.
    """
    name = params.get('rig_calibration', DEFAULT_CALIBRATION)
    try:
        return CALIBRATIONS[name]
    except (KeyError, TypeError):
        raise ParameterError(f'parameter rig_calibration={name!r}: expected one of '
                             + ', '.join(repr(c) for c in CALIBRATIONS)) from None


def controller_gain_V_per_N(params: Mapping) -> float:
    """Numerator of the force controller ``C_f(s)`` [V/N] of the configured reading."""
    return calibration(params).controller_gain_V_per_N


def valve_flow_gain_m3_per_s_V(params: Mapping) -> float:
    """The valve flow gain k_q [m^3/(s V)]: ``valve_flow_gain_m3_per_s_V``, or when it is
    absent or 0, the configured reading's (``RigCalibration.valve_flow_gain_m3_per_s_V``).
    """
    value = params.get('valve_flow_gain_m3_per_s_V', 0.0)
    if isinstance(value, (int, float)) and not isinstance(value, bool) and value == 0:
        return calibration(params).valve_flow_gain_m3_per_s_V
    return value
