"""OpenSees as a computational-model plug-in of seft's core (no rclpy).

:data:`PLUGIN` implements :class:`seft_ros.core.models.ComputationalModel` for a ``structure``
section with an ``opensees`` key; ``setup.py`` registers it under the entry-point group
``seft_ros.computational_models`` as ``opensees``, and the core loads it by that name when a
configuration or a structure's JSON names it. The core never imports this package (no
import cycle: ``tests/seft_ros/test_imports.py``). Each hook imports its module when it is
called: a process that only reads a structure loads neither OpenSees nor matplotlib.
"""

from pathlib import Path
from typing import Any, Callable, Mapping

from seft_ros.opensees.model import KIND

__all__ = ['OpenSeesModels', 'PLUGIN']


class OpenSeesModels:
    """The OpenSees plug-in (:class:`seft_ros.core.models.ComputationalModel`).

    Attributes
    ----------
    name : str
        ``'opensees'``.
    """

    name = KIND

    def structure(self, section: Mapping, *, rigs: Mapping | None = None,
                  where: str = 'structure', base: Path | None = None):
        """:func:`seft_ros.opensees.model.model_structure`."""
        from seft_ros.opensees.model import model_structure
        return model_structure(section, rigs=rigs, where=where, base=base)

    def split(self, structure, specimens: Mapping[str, Mapping[str, Any]], *,
              where: str = 'structure'):
        """:func:`seft_ros.opensees.model.split_model`."""
        from seft_ros.opensees.model import split_model
        return split_model(structure, specimens, where=where)

    def part(self, sub, dt: float):
        """:class:`seft_ros.opensees.part.OpenSeesPart`."""
        from seft_ros.opensees.part import OpenSeesPart
        return OpenSeesPart(sub, dt)

    def reference(self, sub, dt: float, ground_acceleration_m_s2):
        """:func:`seft_ros.opensees.reference.opensees_reference`."""
        from seft_ros.opensees.reference import opensees_reference
        return opensees_reference(sub, dt, ground_acceleration_m_s2)

    def summary(self, run) -> dict:
        """:func:`seft_ros.opensees.report.opensees_entry`."""
        from seft_ros.opensees.report import opensees_entry
        return opensees_entry(run)

    def markdown(self, index: int, run, entry: dict, out_dir, *, reference=None) -> list:
        """:func:`seft_ros.opensees.report.opensees_markdown`."""
        from seft_ros.opensees.report import opensees_markdown
        return opensees_markdown(index, run, entry, out_dir, reference=reference)

    def check_runs(self, runs, *, progress: Callable[[str], None] = print) -> None:
        """:func:`seft_ros.opensees.checks.check_runs`."""
        from seft_ros.opensees.checks import check_runs
        check_runs(runs, progress=progress)


#: The plug-in object the entry point names.
PLUGIN = OpenSeesModels()
