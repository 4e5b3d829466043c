"""The analytical reference of a run, ahead of it, for the live view.

A one-rig test plays a known record: the response of the whole structure to it (paper
Sec. 4, Figure 6; :func:`seft_ros.analysis.reference.reference_from_run`, also for a
hysteretic member) is known before the test starts, and the page draws it beside the test
as the test catches up. Imports no rclpy.
"""

from types import SimpleNamespace
from typing import Any, Mapping

import numpy as np

from seft_msgs_py.errors import SeftError
from seft_msgs_py.parameters import identification_run

__all__ = ['analytical']


def analytical(params: Mapping[str, Any]) -> dict[str, np.ndarray] | None:
    """The whole structure's response to the run's record, at every step.

    Parameters
    ----------
    params : mapping
        The run's resolved parameters (``/seft/run_parameters``).

    Returns
    -------
    dict of str to ndarray (n,), or None
        ``displacement_m`` [m], ``acceleration_m_s2`` [m/s^2] and ``force_N`` (the force on
        the member, the load cell's counterpart) [N] at ``k dt`` for the run's n steps; None
        for a structure (several rigs), an identification excitation, or a record this host
        cannot read (then the page shows the test alone).

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Eq. 2.1 and Sec. 4.
    """
    if params.get('structure', 'none') not in ('none', '', None):
        return None
    if identification_run(params):
        return None
    from seft_ros.analysis.reference import reference_from_run
    from seft_ros.core.ground_motion import prepared_record
    try:
        gm = prepared_record(params)
        ref = reference_from_run(SimpleNamespace(
            params=dict(params), ground_acceleration_m_s2=gm.acceleration_m_s2))
    except (SeftError, KeyError, ValueError, OSError):
        return None
    return {'displacement_m': np.asarray(ref.displacement_m),
            'acceleration_m_s2': np.asarray(ref.acceleration_m_s2),
            'force_N': np.asarray(ref.force_N)}
