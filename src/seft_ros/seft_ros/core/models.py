"""Computational models from other programs: the plug-in point of a structure's model (no
rclpy).

A structure is data (:mod:`seft_ros.core.structure`): matrices, or a model that another
program builds and steps, such as an OpenSeesPy script (:mod:`seft_ros.opensees`). The core
defines what such a model must do and never imports a program's package: an implementation
is a :class:`ComputationalModel` registered under the entry-point group :data:`GROUP` by the
key of the ``structure`` section that names it (``structure: {opensees: ...}``), and is
loaded by that name when a configuration or a structure's JSON is read (after OpenFresco's
``ExperimentalSite`` and ros2_control's hardware interfaces: the core knows the interface,
each implementation lives beside it).

A structure from such a model keeps the matrices of the model's linearization (what the
compensators, the stability check and the pre-run guard work with) and, under the
plug-in's key, the plug-in's own description of the model (``Structure.model``), with
``computational``: the computational part's condensed ``damping_matrix_N_s_per_m`` and
``stiffness_matrix_N_per_m`` (the model without its specimens), which the plug-in's split and
the stability check's scaled structures use.

seft's own package registers ``opensees`` (``setup.py``, ``entry_points``); a lab's package
registers its program the same way.
"""

from functools import lru_cache
from importlib import metadata
from pathlib import Path
from typing import Any, Callable, Mapping, Protocol, runtime_checkable

from seft_msgs_py.errors import ParameterError

__all__ = ['GROUP', 'ComputationalModel', 'model_kinds', 'model_plugin', 'register']

#: The entry-point group of the computational-model plug-ins (name: the section key).
GROUP = 'seft_ros.computational_models'

_LOADED: dict[str, 'ComputationalModel'] = {}


@runtime_checkable
class ComputationalModel(Protocol):
    """A program that models a structure's computational part (the plug-in interface).

    Required: :meth:`structure`, :meth:`split`, :meth:`part`. Optional (looked up with
    ``getattr``; a plug-in without them has the core's behaviour): ``reference(sub, dt,
    ground_acceleration_m_s2)`` (the analytical reference: an
    :class:`~seft_ros.analysis.reference.StructureReference`; default: the linearization's),
    ``summary(run)`` (a JSON-able entry of a run's summary, under the plug-in's name),
    ``markdown(index, run, entry, directory, *, reference)`` (the report's lines of a run),
    ``check_runs(runs, *, progress)`` (refuse runs that cannot run, before they start).

    Attributes
    ----------
    name : str
        The section key (``'opensees'``).
    """

    name: str

    def structure(self, section: Mapping, *, rigs: Mapping | None, where: str,
                  base: Path | None) -> Any:
        """The :class:`~seft_ros.core.structure.Structure` of a ``structure`` section with
        this plug-in's key: the model's linearization, ``model_kind`` and ``model`` set.

        Raises
        ------
        ParameterError
            The section or the model (one line naming the field).
        """

    def split(self, structure: Any, specimens: Mapping[str, Mapping[str, Any]], *,
              where: str) -> Any:
        """The :class:`~seft_ros.core.structure.Substructures` of such a structure
        (:func:`seft_ros.core.structure.split` for it)."""

    def part(self, sub: Any, dt: float) -> Any:
        """The :class:`~seft_ros.core.substructure.ComputationalPart` the builder steps."""


@lru_cache(maxsize=1)
def _entry_points() -> dict[str, metadata.EntryPoint]:
    return {ep.name: ep for ep in metadata.entry_points(group=GROUP)}


def model_kinds() -> tuple[str, ...]:
    """The names of the installed computational-model plug-ins (sorted)."""
    return tuple(sorted(set(_entry_points()) | set(_LOADED)))


def model_plugin(kind: str, *, where: str = 'structure') -> ComputationalModel:
    """The plug-in registered as `kind`, loaded on first use.

    Raises
    ------
    ParameterError
        No plug-in of that name is installed, or it does not load or implement
        :class:`ComputationalModel` (the message names `where` and `kind`).
    """
    plugin = _LOADED.get(kind)
    if plugin is not None:
        return plugin
    ep = _entry_points().get(kind)
    if ep is None:
        raise ParameterError(f'{where}.{kind}: no computational-model plug-in {kind!r} is '
                             f'installed (installed: {", ".join(model_kinds()) or "none"})')
    try:
        plugin = ep.load()
    except Exception as exc:             # a broken plug-in is named, not a traceback
        raise ParameterError(f'{where}.{kind}: the plug-in {ep.value} does not load: '
                             f'{type(exc).__name__}: {exc}') from None
    if not isinstance(plugin, ComputationalModel):
        raise ParameterError(f'{where}.{kind}: {ep.value} is not a computational model '
                             '(structure, split and part expected)')
    _LOADED[kind] = plugin
    return plugin


def register(plugin: ComputationalModel) -> Callable[[], None]:
    """Register `plugin` under its name in this process (a plug-in not installed as a
    package: tests, notebooks); returns the function that removes it."""
    _LOADED[plugin.name] = plugin
    return lambda: _LOADED.pop(plugin.name, None)
