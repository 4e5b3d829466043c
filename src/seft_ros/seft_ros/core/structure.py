"""The whole structure as a linear model: degrees of freedom, which are physical, and on which rig.

A substructure EFT of a structure with dynamics of its own splits the structure's degrees of
freedom (DOFs) into **physical** ones, each tested on a rig whose specimen is the member
that connects that DOF to the ground, and **computational** ones, integrated by the
reference-force builder. This module holds the model as data (after OpenSees/OpenFresco: the
model apart from the experimental setup and from the site that runs it): parsing and checking
the ``structure`` section of a configuration, the whole-structure matrices, and their split
into the specimens' part and the computational part.

The whole structure, relative to the ground (``n`` DOFs, lumped or consistent masses)::

    M x'' + C x' + K x = -M iota xg''                                              (1)

At a physical DOF ``p`` the rig's specimen (``m_p``, ``c_p``, ``k_p``: its mass, its damping
and its stiffness to the ground) is the physical part of the structure; the rest,
``M_c = M - diag_P(m)``, ``C_c = C - diag_P(c)``, ``K_c = K - diag_P(k)``, is computational.
The actuator of rig ``p`` must then apply the effective force plus the interface force of
the computational part (the generalisation of paper Eq. 2.5)::

    f_p = -m_p iota_p xg'' - [M_c (x'' + iota xg'') + C_c x' + K_c x]_p                (2)

With one physical DOF and only a rigid computational mass ``mu = alpha m`` on it,
(2) is paper Eq. 2.5: ``f = -(1 + alpha) m xg'' - alpha m x''``.

Configuration (YAML; the ``structure`` section of a run configuration)::

    structure:
      dofs: [story_1, story_2]              # names (default floor_1, floor_2, ...)
      physical: {story_1: story_1}          # physical DOF -> the rig (ROS namespace) that
                                            # tests it; every other DOF is computational
      # the shear-building shorthand (story i joins floor i-1 and floor i; floor 0 is the
      # ground):
      story_masses_kg: [52.7, 52.7]
      story_stiffnesses_N_per_m: [2.11e5, 2.11e5]
      story_damping_N_s_per_m: [903.278, 0.0]   # or modal_damping_ratios, rayleigh_damping
      # or the general form:
      # mass_matrix_kg: [[...], ...]
      # stiffness_matrix_N_per_m: [[...], ...]
      # damping_matrix_N_s_per_m: [[...], ...]  # or modal_damping_ratios, rayleigh_damping
      # influence: [1.0, 1.0]                   # iota (default: ones)

    rigs:                                   # per-rig parameters (its namespace's nodes)
      story_1: {rig_model: servohydraulic, stiffness_N_per_m: 2.11e5}

Or a model of the whole structure in another program, under the key of its plug-in
(:mod:`seft_ros.core.models`; ``opensees``: an OpenSeesPy model, the DOFs it names, each
rig's specimen elements), with ``physical``; the matrices are then the model's
linearization.

Damping, one of: ``story_damping_N_s_per_m`` (shear building: a dashpot per story),
``damping_matrix_N_s_per_m``, ``modal_damping_ratios`` (one ratio per mode in order of
frequency, or one for all: ``C = M Phi diag(2 zeta_i omega_i) Phi^T M`` with mass-normalised
mode shapes, Chopra, Dynamics of Structures, Sec. 11.5) or ``rayleigh_damping:
{mass_coefficient_1_per_s: a0, stiffness_coefficient_s: a1}`` (``C = a0 M + a1 K``,
Chopra Sec. 11.4).

Checks (one error line naming the field): every per-DOF field of one size (the field that
differs from the others is named); ``M`` symmetric positive definite, ``K`` symmetric
positive definite (the whole structure stands on the ground), ``C`` symmetric positive
semi-definite (symmetric to 1e-8 of the matrix's largest entry, a matrix printed to 9
significant digits; the matrix used is then ``(A + A^T) / 2``); modal damping ratios below 1
(critical); an influence vector not all zero; a physical DOF has a lumped mass not smaller
than its specimen's, no mass coupling to other DOFs, a spring to the ground (a specimen joins
its DOF to the ground: a story between two floors cannot be one) whose stiffness (the row sum
of ``K``) equals its specimen's; each rig tests one DOF; every rig section names a rig of
``physical``.
"""

from collections import Counter
from dataclasses import dataclass, field, replace
import json
import math
import re
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.parameters import TEST_PARAMETERS
from seft_ros.core.models import model_kinds, model_plugin

__all__ = ['Structure', 'parse_structure', 'Substructures', 'split', 'STRUCTURE_KEYS',
           'NAME_PATTERN', 'Link', 'NO_STRUCTURE', 'structure_of', 'rig_parameters',
           'reduces_to_study', 'study_parameters', 'study_structure', 'STUDY_DOF', 'STUDY_RIG',
           'TestSetup', 'test_setup']

#: The ``structure`` parameter of a run without one (the reference study's single rig).
NO_STRUCTURE = 'none'
#: The degree of freedom of the reference study's test (:func:`study_structure`).
STUDY_DOF = 'specimen'
#: The rig of the reference study's test: the root namespace (its topics ``/seft/...``).
STUDY_RIG = ''
#: Names of DOFs and rigs: a ROS name token (a rig's name is its nodes' namespace).
NAME_PATTERN = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')
#: The keys of a ``structure`` section.
STRUCTURE_KEYS = ('dofs', 'physical', 'story_masses_kg', 'story_stiffnesses_N_per_m',
                  'story_damping_N_s_per_m', 'mass_matrix_kg', 'stiffness_matrix_N_per_m',
                  'damping_matrix_N_s_per_m', 'modal_damping_ratios', 'rayleigh_damping',
                  'influence')
_SHEAR = ('story_masses_kg', 'story_stiffnesses_N_per_m')
_MATRICES = ('mass_matrix_kg', 'stiffness_matrix_N_per_m')
_DAMPING = ('story_damping_N_s_per_m', 'damping_matrix_N_s_per_m', 'modal_damping_ratios',
            'rayleigh_damping')
#: Relative tolerance of the definiteness and specimen checks.
_TOL = 1e-9
#: Relative tolerance of the symmetry check, of the matrix's largest entry: one unit in the
#: 9th significant digit of that entry. A matrix an FE program assembled symmetric and
#: printed to 9 digits may differ across its diagonal by one unit of the last digit
#: (the sums of its assembly round either side of a printed digit); a matrix typed wrong
#: differs by far more (k_nonsym: 5 %). The matrix used is then (A + A^T) / 2, a change
#: of at most half of this: far below any stiffness, mass or damping a lab can measure.
_SYMMETRY_TOL = 1e-8
#: The rigid computational mass ratio is rounded to this many decimals (far below any mass a
#: lab can weigh), so that a mass written as (1 + alpha) m gives the study's alpha exactly.
ALPHA_DECIMALS = 12


@dataclass(frozen=True)
class Link:
    """A spring (and dashpot) of the structure between two DOFs, or a DOF and the ground.

    Attributes
    ----------
    i : int
        First DOF.
    j : int or None
        Second DOF (None: the ground).
    name : str
        ``'<dof_i>-<dof_j>'`` or ``'<dof_i>-ground'``; for a shear building, story ``s``
        (``'story_s'``) joins floor s-1 and floor s.
    """

    i: int
    j: int | None
    name: str


@dataclass(frozen=True)
class Structure:
    """A linear structure, its DOFs split into physical (on a rig) and computational.

    Parameters
    ----------
    dofs : tuple of str, length n
        DOF names.
    mass_kg : ndarray, shape (n, n)
        Mass matrix M [kg], symmetric positive definite.
    damping_N_s_per_m : ndarray, shape (n, n)
        Damping matrix C [N s/m], symmetric positive semi-definite.
    stiffness_N_per_m : ndarray, shape (n, n)
        Stiffness matrix K [N/m], symmetric positive definite.
    influence : ndarray, shape (n,)
        Ground-motion influence vector iota [-] (Eq. 1).
    physical : mapping of str to str
        Physical DOF name -> rig name, in DOF order.
    rigs : mapping of str to mapping
        Rig name -> its parameter overrides (every rig of `physical` has an entry, maybe
        empty).
    links : tuple of Link
        The springs whose deformation the report gives (story drifts of a shear building).
    damping_from : str
        The key of the ``structure`` section the damping came from (error messages name
        what the user wrote).
    model_kind : str or None
        A structure from a model of another program: the name of its plug-in
        (:mod:`seft_ros.core.models`, e.g. ``'opensees'``); the matrices are then the model's
        linearization. None: the matrices are the structure.
    model : mapping or None
        The plug-in's description of the model (JSON-able; its ``computational`` entry holds
        the computational part's condensed ``damping_matrix_N_s_per_m`` and
        ``stiffness_matrix_N_per_m``).

    Attributes
    ----------
    n : int
        Number of DOFs.
    physical_index : tuple of int
        Indices of the physical DOFs, in DOF order (``P``).
    computational_index : tuple of int
        Indices of the computational DOFs (``Q``).
    rig_names : tuple of str
        The rigs, in the order of ``physical_index``.
    """

    dofs: tuple
    mass_kg: np.ndarray
    damping_N_s_per_m: np.ndarray
    stiffness_N_per_m: np.ndarray
    influence: np.ndarray
    physical: Mapping[str, str]
    rigs: Mapping[str, Mapping[str, Any]]
    links: tuple = field(default=())
    damping_from: str = 'damping_matrix_N_s_per_m'
    model_kind: str | None = None
    model: Mapping[str, Any] | None = None

    @property
    def n(self) -> int:
        """Number of DOFs."""
        return len(self.dofs)

    @property
    def physical_index(self) -> tuple:
        """Indices of the physical DOFs (``P``), in DOF order."""
        return tuple(i for i, d in enumerate(self.dofs) if d in self.physical)

    @property
    def computational_index(self) -> tuple:
        """Indices of the computational DOFs (``Q``), in DOF order."""
        return tuple(i for i, d in enumerate(self.dofs) if d not in self.physical)

    @property
    def rig_names(self) -> tuple:
        """The rigs, in the order of :attr:`physical_index`."""
        return tuple(self.physical[self.dofs[i]] for i in self.physical_index)

    def dof_of_rig(self, rig: str) -> str:
        """The DOF that `rig` tests (KeyError if none)."""
        for dof, name in self.physical.items():
            if name == rig:
                return dof
        raise KeyError(rig)

    def modes(self) -> tuple[np.ndarray, np.ndarray]:
        """Undamped natural frequencies [Hz] (ascending, shape (n,)) and mass-normalised mode
        shapes (columns, shape (n, n)) of the whole structure (``scipy.linalg.eigh(K, M)``)."""
        from scipy.linalg import eigh
        w2, phi = eigh(self.stiffness_N_per_m, self.mass_kg)
        return np.sqrt(np.maximum(w2, 0.0)) / (2.0 * math.pi), phi

    def to_json(self) -> str:
        """The canonical JSON of the structure (the ``structure`` parameter of the nodes).

        Floats are written by :func:`repr`, so :meth:`from_json` gives the same numbers.
        """
        doc = {
            'dofs': list(self.dofs),
            'mass_matrix_kg': self.mass_kg.tolist(),
            'damping_matrix_N_s_per_m': self.damping_N_s_per_m.tolist(),
            'stiffness_matrix_N_per_m': self.stiffness_N_per_m.tolist(),
            'influence': self.influence.tolist(),
            'physical': dict(self.physical),
            'rigs': {r: dict(v) for r, v in self.rigs.items()},
            'links': [[lk.i, lk.j, lk.name] for lk in self.links],
            'damping_from': self.damping_from,
        }
        if self.model_kind is not None:
            doc[self.model_kind] = dict(self.model or {})
        return json.dumps(doc, sort_keys=True, separators=(',', ':'))

    @classmethod
    def from_json(cls, text: str, *, where: str = 'parameter structure') -> 'Structure':
        """Read :meth:`to_json`'s text back (checked as :func:`parse_structure` checks).

        Raises
        ------
        ParameterError
            Not JSON, or not a valid structure; the message starts with `where`.
        """
        try:
            doc = json.loads(text)
        except (TypeError, ValueError) as exc:
            raise ParameterError(f'{where}: expected the JSON of a structure ({exc})') from None
        if not isinstance(doc, dict):
            raise ParameterError(f'{where}: expected the JSON object of a structure')
        links = doc.pop('links', None)
        rigs = doc.pop('rigs', {})
        damping_from = doc.pop('damping_from', 'damping_matrix_N_s_per_m')
        extra = [k for k in doc if k not in STRUCTURE_KEYS]
        kind = extra[0] if len(extra) == 1 and extra[0] in model_kinds() else None
        model = doc.pop(kind) if kind is not None else None
        out = parse_structure(doc, rigs=rigs, where=where)
        out = replace(out, damping_from=str(damping_from))
        if kind is not None:
            out = replace(out, model_kind=kind, model=MappingProxyType(dict(model)))
        if links is not None:
            try:
                parsed = tuple(Link(int(i), None if j is None else int(j), str(name))
                               for i, j, name in links)
            except (TypeError, ValueError):
                raise ParameterError(f'{where}: links: expected [i, j, name] triples') \
                    from None
            out = replace(out, links=parsed)
        return out


def _fail(where: str, key: str, message: str) -> ParameterError:
    return ParameterError(f'{where}.{key}: {message}')


def _numbers(where: str, key: str, value, n: int | None = None, *, positive: bool = False,
             nonnegative: bool = False) -> np.ndarray:
    """A list of finite numbers (length `n` if given)."""
    what = 'numbers' + (' > 0' if positive else ' >= 0' if nonnegative else '')
    count = f'{n} ' if n is not None else ''
    if (not isinstance(value, (list, tuple)) or not value
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise _fail(where, key, f'expected a list of {count}{what}, got {value!r}')
    arr = np.asarray(value, dtype=float)
    if n is not None and arr.shape[0] != n:
        raise _fail(where, key, f'expected {n} {what} (one per dof), got {arr.shape[0]}')
    if not np.all(np.isfinite(arr)) or (positive and np.any(arr <= 0)) or (
            nonnegative and np.any(arr < 0)):
        raise _fail(where, key, f'expected {what}, got {value!r}')
    return arr


def _matrix(where: str, key: str, value, n: int | None) -> np.ndarray:
    """A square matrix of finite numbers (n x n if given), symmetric."""
    rows = value if isinstance(value, (list, tuple)) else None
    ok = rows is not None and rows and all(
        isinstance(r, (list, tuple)) and r and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in r) for r in rows)
    size = n if n is not None else (len(rows) if rows else 0)
    if not ok or len(rows) != size or any(len(r) != size for r in rows):
        raise _fail(where, key, f'expected a {size} x {size} matrix (a list of {size} rows of '
                    f'{size} numbers), got {value!r}')
    arr = np.asarray(rows, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise _fail(where, key, 'expected finite numbers')
    scale = max(float(np.max(np.abs(arr))), 1e-300)
    if np.max(np.abs(arr - arr.T)) > _SYMMETRY_TOL * scale:
        i, j = np.unravel_index(int(np.argmax(np.abs(arr - arr.T))), arr.shape)
        raise _fail(where, key, f'expected a symmetric matrix (to {_SYMMETRY_TOL:g} of '
                    f'its largest entry), but row {i + 1} column {j + 1} is '
                    f'{float(arr[i, j])!r} and row {j + 1} column {i + 1} is '
                    f'{float(arr[j, i])!r}')
    return 0.5 * (arr + arr.T)              # nothing downstream sees the round-off


def _definite(where: str, key: str, matrix: np.ndarray, *, semi: bool = False,
              dofs=()) -> None:
    w = np.linalg.eigvalsh(matrix)
    scale = max(float(np.max(np.abs(w))), 1e-300)
    if (w.min() < -_TOL * scale) if semi else (w.min() <= _TOL * scale):
        kind = 'positive semi-definite' if semi else 'positive definite'
        # a dof without mass named (a new user's massless deck read only 'its smallest
        # eigenvalue is 0'; session 36)
        massless = [str(d) for d, m in zip(dofs, np.diag(matrix)) if m <= _TOL * scale]
        why = ('' if semi else ' (a mode without stiffness: every dof must be held to the '
               'ground through springs)' if 'stiffness' in key else
               f" (dof {', '.join(map(repr, massless))} without mass: every dof of the matrix "
               'form carries a mass; a massless node belongs in an OpenSees model, which '
               'condenses it)' if 'mass' in key and massless else '')
        raise _fail(where, key, f'expected a {kind} matrix, but its smallest eigenvalue is '
                    f'{w.min():.6g}' + why)


def _shear_building(where: str, section: Mapping, n: int):
    m = _numbers(where, 'story_masses_kg', section['story_masses_kg'], n, positive=True)
    k = _numbers(where, 'story_stiffnesses_N_per_m', section['story_stiffnesses_N_per_m'], n,
                 positive=True)
    mass = np.diag(m)
    stiff = _chain(k)
    damping = None
    if 'story_damping_N_s_per_m' in section:
        c = _numbers(where, 'story_damping_N_s_per_m', section['story_damping_N_s_per_m'], n,
                     nonnegative=True)
        damping = _chain(c)
    return mass, stiff, damping


def _chain(values: np.ndarray) -> np.ndarray:
    """The matrix of a chain of springs: spring i joins DOF i-1 (the ground for i = 0) to i."""
    n = values.shape[0]
    out = np.zeros((n, n))
    for i, v in enumerate(values):
        out[i, i] += v
        if i > 0:
            out[i - 1, i - 1] += v
            out[i - 1, i] -= v
            out[i, i - 1] -= v
    return out


def _modal_damping(where: str, ratios, mass: np.ndarray, stiff: np.ndarray) -> np.ndarray:
    from scipy.linalg import eigh
    n = mass.shape[0]
    if isinstance(ratios, (int, float)) and not isinstance(ratios, bool):
        ratios = [ratios]
    zeta = _numbers(where, 'modal_damping_ratios', ratios, nonnegative=True)
    if np.any(zeta >= 1.0):
        raise _fail(where, 'modal_damping_ratios', 'expected ratios < 1 (fractions of '
                    'critical damping: 0.05 is 5 %; at 1 a mode no longer oscillates), got '
                    f'{ratios!r}')
    if zeta.shape[0] == 1:
        zeta = np.full(n, zeta[0])
    elif zeta.shape[0] != n:
        raise _fail(where, 'modal_damping_ratios', f'expected one ratio for all modes or {n} '
                    f'(one per mode), got {zeta.shape[0]}')
    w2, phi = eigh(stiff, mass)                       # phi^T M phi = I
    omega = np.sqrt(np.maximum(w2, 0.0))
    mphi = mass @ phi
    return mphi @ np.diag(2.0 * zeta * omega) @ mphi.T


def _rayleigh(where: str, value, mass: np.ndarray, stiff: np.ndarray) -> np.ndarray:
    keys = ('mass_coefficient_1_per_s', 'stiffness_coefficient_s')
    if not isinstance(value, Mapping) or set(value) - set(keys) or not set(value):
        raise _fail(where, 'rayleigh_damping', f'expected a mapping with {keys[0]} and/or '
                    f'{keys[1]}, got {value!r}')
    coeff = []
    for key in keys:
        v = value.get(key, 0.0)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (
                math.isfinite(v) and v >= 0):
            raise _fail(where, f'rayleigh_damping.{key}', f'expected a number >= 0, got {v!r}')
        coeff.append(float(v))
    return coeff[0] * mass + coeff[1] * stiff


def _links(stiff: np.ndarray, dofs, shear: bool) -> tuple:
    n = len(dofs)
    if shear:
        return tuple(Link(i, i - 1 if i else None, f'story_{i + 1}') for i in range(n))
    out = []
    for i in range(n):
        ground = float(np.sum(stiff[i]))
        if abs(ground) > _TOL * float(np.max(np.abs(stiff))):
            out.append(Link(i, None, f'{dofs[i]}-ground'))
        for j in range(i + 1, n):
            if stiff[i, j] != 0.0:
                out.append(Link(i, j, f'{dofs[i]}-{dofs[j]}'))
    return tuple(out)


def _dof_count(where: str, section: Mapping, form: tuple) -> int:
    """The number of DOFs: the size most of the per-DOF fields given agree on (the first
    field's of `form` on a tie). A field of another size is named, with the fields that
    agree (a mass matrix of the wrong size is the mass matrix's error, not ``dofs``'s);
    ``dofs`` of the wrong size is left to its own check."""
    keys = ('dofs', *form, 'story_damping_N_s_per_m', 'damping_matrix_N_s_per_m', 'influence')
    sizes = {k: len(section[k]) for k in keys
             if k in section and isinstance(section[k], (list, tuple))}
    if form[0] not in sizes:
        return 0
    counts = Counter(sizes.values())
    most = max(counts.values())
    n = sizes[form[0]] if counts[sizes[form[0]]] == most else next(
        v for v, c in counts.items() if c == most)
    for key, size in sizes.items():
        if size != n and key != 'dofs':
            agree = [k for k, v in sizes.items() if v == n]
            matrix = key in (*_MATRICES, 'damping_matrix_N_s_per_m')
            names = ' and '.join([', '.join(agree[:-1]), agree[-1]] if agree[:-1] else agree)
            raise _fail(where, key, f'has {size} {"rows" if matrix else "entries"}, but '
                        f'{names} {"give" if len(agree) > 1 else "gives"} {n} dofs; '
                        f'expected {f"a {n} x {n} matrix" if matrix else f"{n} entries"} '
                        f'(one {"row " if matrix else ""}per dof)')
    return n


def parse_structure(section: Mapping, *, rigs: Mapping | None = None,
                    where: str = 'structure', base=None) -> Structure:
    """Check a ``structure`` section (and its ``rigs`` section) and build the model.

    Parameters
    ----------
    section : mapping
        The ``structure`` section (module notes for the keys).
    rigs : mapping of str to mapping, optional
        The ``rigs`` section: rig name -> parameter overrides (checked against the schema by
        :func:`rig_parameters`, not here).
    where : str
        Prefix of the error messages (the file and section, e.g.
        ``'config/two_story.yaml: structure'``).
    base : path, optional
        The configuration's directory (an OpenSees model file is found there).

    Returns
    -------
    Structure
        With a model plug-in's key (``opensees``): the plug-in's structure
        (:func:`seft_ros.core.models.model_plugin`).

    Raises
    ------
    ParameterError
        One line naming the field: an unknown key, a missing or a doubled form, a list or a
        matrix of another size than the other fields', a number out of range (a modal damping
        ratio of 1 or more), an influence vector all zero, a matrix that is not symmetric or
        not positive definite where it must be, a DOF or rig name that is not a ROS name, a
        rig that tests two DOFs, a rig section for no physical DOF, no physical DOF.
    """
    if not isinstance(section, Mapping):
        raise ParameterError(f'{where}: expected a mapping (module seft_ros.core.structure '
                             f'lists the keys), got {section!r}')
    unknown = sorted(set(section) - set(STRUCTURE_KEYS))
    if unknown:
        kinds = model_kinds()
        plugins = [k for k in unknown if k in kinds]
        if not plugins:
            raise _fail(where, unknown[0], 'unknown key (expected one of '
                        + ', '.join(STRUCTURE_KEYS) + ', or a model plug-in: '
                        + (', '.join(kinds) or 'none installed') + ')')
        # a model of another program (a plug-in: seft_ros.core.models)
        return model_plugin(plugins[0], where=where).structure(section, rigs=rigs, where=where,
                                                               base=base)
    shear = [k for k in _SHEAR if k in section]
    general = [k for k in _MATRICES if k in section]
    if shear and general:
        raise _fail(where, general[0], f'give either the shear-building form ({_SHEAR[0]}, '
                    f'{_SHEAR[1]}) or the general form ({_MATRICES[0]}, {_MATRICES[1]}), not '
                    'both')
    form = _SHEAR if shear else _MATRICES
    missing = [k for k in form if k not in section]
    if missing or not (shear or general):
        raise _fail(where, missing[0] if missing else _SHEAR[0],
                    f'missing (the structure needs {form[0]} and {form[1]}, or '
                    f'{_MATRICES[0]} and {_MATRICES[1]})')
    damping_keys = [k for k in _DAMPING if k in section]
    if len(damping_keys) > 1:
        raise _fail(where, damping_keys[1], f'give one damping ({", ".join(_DAMPING)}), got '
                    f'{damping_keys[0]} too')
    if shear is False or not shear:
        if 'story_damping_N_s_per_m' in section:
            raise _fail(where, 'story_damping_N_s_per_m', 'belongs to the shear-building form; '
                        'with matrices give damping_matrix_N_s_per_m, modal_damping_ratios or '
                        'rayleigh_damping')
    if shear and 'damping_matrix_N_s_per_m' in section:
        raise _fail(where, 'damping_matrix_N_s_per_m', 'belongs to the general form; with '
                    'story masses give story_damping_N_s_per_m, modal_damping_ratios or '
                    'rayleigh_damping')
    # the number of DOFs
    first = section[form[0]]
    n = _dof_count(where, section, form)
    if n < 1:
        raise _fail(where, form[0], f'expected at least one dof, got {first!r}')
    dofs = section.get('dofs')
    if dofs is None:
        dofs = [f'floor_{i + 1}' for i in range(n)] if shear else [f'dof_{i + 1}'
                                                                   for i in range(n)]
    if (not isinstance(dofs, (list, tuple)) or len(dofs) != n
            or not all(isinstance(d, str) for d in dofs)):
        raise _fail(where, 'dofs', f'expected a list of {n} names (one per dof), got {dofs!r}')
    for d in dofs:
        if not NAME_PATTERN.match(d):
            raise _fail(where, 'dofs', f'{d!r}: expected a name of letters, digits and '
                        'underscores that starts with a letter')
    if len(set(dofs)) != n:
        dup = next(d for d in dofs if list(dofs).count(d) > 1)
        raise _fail(where, 'dofs', f'{dup!r} is named twice')
    if shear:
        mass, stiff, damping = _shear_building(where, section, n)
    else:
        mass = _matrix(where, 'mass_matrix_kg', section['mass_matrix_kg'], n)
        stiff = _matrix(where, 'stiffness_matrix_N_per_m', section['stiffness_matrix_N_per_m'],
                        n)
        damping = None
        if 'damping_matrix_N_s_per_m' in section:
            damping = _matrix(where, 'damping_matrix_N_s_per_m',
                              section['damping_matrix_N_s_per_m'], n)
    _definite(where, form[0], mass, dofs=dofs)
    _definite(where, form[1], stiff)
    if 'modal_damping_ratios' in section:
        damping = _modal_damping(where, section['modal_damping_ratios'], mass, stiff)
    elif 'rayleigh_damping' in section:
        damping = _rayleigh(where, section['rayleigh_damping'], mass, stiff)
    elif damping is None:
        raise _fail(where, 'story_damping_N_s_per_m' if shear else 'damping_matrix_N_s_per_m',
                    'missing: give the damping (' + ', '.join(
                        k for k in _DAMPING if (k != 'damping_matrix_N_s_per_m' or not shear)
                        and (k != 'story_damping_N_s_per_m' or shear)) + ')')
    _definite(where, damping_keys[0] if damping_keys else 'damping', damping, semi=True)
    influence = np.ones(n)
    if 'influence' in section:
        influence = _numbers(where, 'influence', section['influence'], n)
        if not np.any(influence):
            raise _fail(where, 'influence', "all zero: the ground motion loads no dof (the "
                        "load -M iota xg'' of Eq. 1 is zero); expected a non-zero entry "
                        '(default: ones)')
    physical = section.get('physical')
    if not isinstance(physical, Mapping) or not physical:
        raise _fail(where, 'physical', 'expected a mapping of at least one dof to the rig that '
                    f'tests it ({{{dofs[0]}: <rig name>}}), got {physical!r}')
    for dof, rig in physical.items():
        if dof not in dofs:
            raise _fail(where, 'physical', f'{dof!r} is not a dof (dofs: {", ".join(dofs)})')
        if not isinstance(rig, str) or not NAME_PATTERN.match(rig):
            raise _fail(where, f'physical.{dof}', f'expected a rig name of letters, digits and '
                        f'underscores that starts with a letter, got {rig!r}')
    used = list(physical.values())
    for rig in used:
        if used.count(rig) > 1:
            both = [d for d, r in physical.items() if r == rig]
            raise _fail(where, 'physical', f'rig {rig!r} tests {len(both)} dofs ('
                        f'{", ".join(both)}); a rig tests one dof')
    ordered = {d: physical[d] for d in dofs if d in physical}
    rigs = {} if rigs is None else rigs
    if not isinstance(rigs, Mapping):
        raise ParameterError(f'{_rigs_where(where)}: expected a mapping of rig names to their '
                             f'parameters, got {rigs!r}')
    for rig, values in rigs.items():
        if rig not in used:
            raise ParameterError(f'{_rigs_where(where)}.{rig}: no dof of structure.physical '
                                 f'names this rig (rigs: {", ".join(used)})')
        if not isinstance(values, Mapping):
            raise ParameterError(f'{_rigs_where(where)}.{rig}: expected a mapping of '
                                 f'parameters, got {values!r}')
    rig_values = MappingProxyType({r: MappingProxyType(dict(rigs.get(r, {})))
                                   for r in ordered.values()})
    return Structure(tuple(dofs), mass, damping, stiff, influence,
                     MappingProxyType(ordered), rig_values, _links(stiff, dofs, bool(shear)),
                     damping_keys[0] if damping_keys else 'damping_matrix_N_s_per_m')


def _rigs_where(where: str) -> str:
    """The ``rigs`` section's name beside a ``structure`` section's `where`."""
    return where[:-len('structure')] + 'rigs' if where.endswith('structure') else where + ' rigs'


# -- the split into specimens and computational part ----------------------------------------


@dataclass(frozen=True)
class Substructures:
    """A structure split into the rigs' specimens and the computational part (Eq. 2).

    Attributes
    ----------
    structure : Structure
    specimen_mass_kg, specimen_damping_N_s_per_m, specimen_stiffness_N_per_m : ndarray (n_p,)
        The specimens' m, c, k, in the order of ``structure.physical_index``.
    rigid_mass_kg : ndarray (n_p,)
        ``mu_p = M_pp - m_p``: the computational mass riding on each physical DOF [kg].
    alpha : ndarray (n_p,)
        ``mu_p / m_p`` (rounded to ``ALPHA_DECIMALS`` decimals).
    mass_c_kg, damping_c_N_s_per_m, stiffness_c_N_per_m : ndarray (n, n)
        The computational part ``M_c``, ``C_c``, ``K_c``.
    """

    structure: Structure
    specimen_mass_kg: np.ndarray
    specimen_damping_N_s_per_m: np.ndarray
    specimen_stiffness_N_per_m: np.ndarray
    rigid_mass_kg: np.ndarray
    alpha: np.ndarray
    mass_c_kg: np.ndarray
    damping_c_N_s_per_m: np.ndarray
    stiffness_c_N_per_m: np.ndarray

    @property
    def coupled(self) -> bool:
        """Whether anything but rigid masses is computational (springs, dashpots or DOFs)."""
        s = self.structure
        return bool(s.computational_index) or bool(np.any(self.damping_c_N_s_per_m)) or bool(
            np.any(self.stiffness_c_N_per_m))

    @property
    def coupled_rigs(self) -> tuple:
        """The rigs whose DOF carries computational springs or dashpots (a row of ``K_c``
        or ``C_c`` not zero), in the order of the structure's rigs: their loop is closed
        again through the computational part."""
        s = self.structure
        return tuple(r for r, i in zip(s.rig_names, s.physical_index)
                     if self.stiffness_c_N_per_m[i].any() or self.damping_c_N_s_per_m[i].any())


def split(structure: Structure, specimens: Mapping[str, Mapping[str, Any]], *,
          where: str = 'structure', study_alpha: float | None = None) -> Substructures:
    """Split the structure into the specimens of its rigs and the computational part.

    Parameters
    ----------
    structure : Structure
    specimens : mapping of str to mapping
        Rig name -> its resolved parameters (``mass_kg``, ``damping_N_s_per_m``,
        ``stiffness_N_per_m``: a yielding member's elastic stiffness).
    where : str
        Prefix of the error messages.
    study_alpha : float, optional
        The mass ratio of a one-DOF structure as the user gave it (the study's ``alpha``):
        kept exactly instead of ``mu / m`` rounded.

    Returns
    -------
    Substructures

    Raises
    ------
    ParameterError
        A rig without parameters, a physical DOF coupled by mass to another DOF, a mass
        smaller than the specimen's, a physical DOF with no spring to the ground (a member
        between two DOFs cannot be a specimen), or a stiffness to the ground (the row sum of
        ``K``) that differs from the specimen's: the structure's physical part disagrees with the
        rig's specimen (the message gives both values).
    """
    if structure.model_kind is not None:     # a plug-in's model: its specimens, its split
        return model_plugin(structure.model_kind, where=where).split(structure, specimens,
                                                                     where=where)
    idx = structure.physical_index
    m = np.zeros(len(idx))
    c = np.zeros(len(idx))
    k = np.zeros(len(idx))
    mass = structure.mass_kg
    stiff = structure.stiffness_N_per_m
    scale = float(np.max(np.abs(stiff)))
    for j, i in enumerate(idx):
        dof = structure.dofs[i]
        rig = structure.physical[dof]
        if rig not in specimens:
            raise ParameterError(f'{where}.physical.{dof}: rig {rig!r} has no parameters')
        p = specimens[rig]
        m[j], c[j], k[j] = (float(p['mass_kg']), float(p['damping_N_s_per_m']),
                            float(p['stiffness_N_per_m']))
        others = [o for o in range(structure.n) if o != i and mass[i, o] != 0.0]
        if others:
            raise ParameterError(
                f'{where}: physical dof {dof!r} is coupled by mass to '
                f'{structure.dofs[others[0]]!r}; a physical dof needs a lumped mass (a zero '
                'off-diagonal mass)')
        if mass[i, i] < m[j] * (1.0 - _TOL):
            raise ParameterError(
                f'{where}: the mass at physical dof {dof!r} is {float(mass[i, i])!r} kg, less '
                f"than rig {rig}'s specimen mass_kg={float(m[j])!r}: the structure disagrees "
                'with the specimen')
        ground = float(np.sum(stiff[i]))
        if abs(ground) <= 1e-6 * scale < k[j]:
            grounded = [structure.dofs[o] for o in range(structure.n)
                        if abs(float(np.sum(stiff[o]))) > 1e-6 * scale]
            raise ParameterError(
                f'{where}.physical: dof {dof!r} has no spring to the ground (the row sum of '
                f'the stiffness matrix is {ground:.6g} N/m): it is joined to other dofs only, '
                f"but a specimen joins its dof to the ground (rig {rig}'s actuator reacts on "
                'the lab floor), so a member between two dofs (a story above the first) '
                'cannot be one; test a dof with a spring to the ground (here: '
                f'{", ".join(grounded)})')
        damped = float(structure.damping_N_s_per_m[i, i])
        if damped < c[j] * (1.0 - 1e-6):
            raise ParameterError(
                f'{where}.{structure.damping_from}: gives physical dof {dof!r} a damping of '
                f'{damped:.6g} N s/m (the diagonal of the damping matrix), less than rig '
                f"{rig}'s specimen alone, damping_N_s_per_m={float(c[j]):.6g}: the computational "
                'part would add negative damping there (give the structure at least the '
                "specimen's damping at that dof, or declare the specimen's own)")
        if abs(ground - k[j]) > 1e-6 * max(scale, k[j]):
            raise ParameterError(
                f'{where}: the stiffness to the ground at physical dof {dof!r} is {ground!r} N/m '
                f"(the row sum of the stiffness matrix), but rig {rig}'s specimen has "
                f'stiffness_N_per_m={float(k[j])!r}: the structure disagrees with the specimen')
    rigid = np.array([max(mass[i, i] - m[j], 0.0) for j, i in enumerate(idx)])
    alpha = np.round(rigid / m, ALPHA_DECIMALS)
    if study_alpha is not None and len(idx) == 1:
        alpha = np.array([float(study_alpha)])
    mc = mass.copy()
    cc = structure.damping_N_s_per_m.copy()
    kc = stiff.copy()
    for j, i in enumerate(idx):
        mc[i, i] = rigid[j]
        cc[i, i] -= c[j]
        kc[i, i] -= k[j]
    # what is left of a specimen's own damping or stiffness by rounding (a structure written
    # with the specimen's numbers) is no computational dashpot or spring
    for part, whole in ((cc, structure.damping_N_s_per_m), (kc, stiff)):
        part[np.abs(part) <= _TOL * max(float(np.max(np.abs(whole))), 1e-300)] = 0.0
    return Substructures(structure, m, c, k, rigid, alpha, mc, cc, kc)


# -- runs ----------------------------------------------------------------------------------


def study_structure(params: Mapping[str, Any]) -> Structure:
    """The reference study's test as a structure: one physical DOF (:data:`STUDY_DOF`)
    carrying the rigid computational mass ``alpha m``, tested on the rig of the root
    namespace (:data:`STUDY_RIG`).

    ``M = [(1 + alpha) m]``, ``C = [c]``, ``K = [k]`` from ``alpha``, ``mass_kg``,
    ``damping_N_s_per_m`` and ``stiffness_N_per_m`` (a yielding member's elastic
    stiffness); Eq. 2 of this module is then paper Eq. 2.5.
    """
    m, c, k = (float(params['mass_kg']), float(params['damping_N_s_per_m']),
               float(params['stiffness_N_per_m']))
    total = (1.0 + float(params['alpha'])) * m
    return Structure((STUDY_DOF,), np.array([[total]]), np.array([[c]]), np.array([[k]]),
                     np.ones(1), MappingProxyType({STUDY_DOF: STUDY_RIG}),
                     MappingProxyType({STUDY_RIG: MappingProxyType({})}),
                     (Link(0, None, f'{STUDY_DOF}-ground'),))


def is_study(params: Mapping[str, Any]) -> bool:
    """Whether a run is the reference study's test (no ``structure`` parameter)."""
    return params.get('structure', NO_STRUCTURE) in (None, '', NO_STRUCTURE)


def structure_of(params: Mapping[str, Any]) -> Structure:
    """The run's structure: its ``structure`` parameter, or the study's one-DOF structure
    (:func:`study_structure`) without one.

    Raises
    ------
    ParameterError
        The parameter is not the JSON of a valid structure.
    """
    if is_study(params):
        return study_structure(params)
    return Structure.from_json(params['structure'])


def rig_parameters(params: Mapping[str, Any], structure: Structure, rig: str, *,
                   where: str = 'rigs') -> dict[str, Any]:
    """The resolved parameters of one rig's nodes: the run's, updated by the rig's section.

    Parameters
    ----------
    params : mapping
        The run's resolved parameters.
    structure : Structure
    rig : str
        A rig of ``structure.physical``.
    where : str
        Prefix of the error messages.

    Returns
    -------
    dict
        ``params`` with the rig's overrides, validated against the schema.

    Raises
    ------
    ParameterError
        An unknown rig, a parameter of the test set per rig, or a value the schema refuses
        (the message names the rig section and the parameter).
    """
    from seft_msgs_py import parameters
    if rig not in structure.rigs:
        raise ParameterError(f'{where}: no rig {rig!r} (rigs: {", ".join(structure.rigs)})')
    out = dict(params)
    for name, value in structure.rigs[rig].items():
        if name in TEST_PARAMETERS:
            raise ParameterError(f'{where}.{rig}.{name}: a parameter of the whole test, not of '
                                 'one rig; set it for all')
        out[name] = parameters.validate_value(name, value, where=f'{where}.{rig}')
    return out


@dataclass(frozen=True)
class TestSetup:
    """What a test is made of: the split structure and each rig's parameters.

    Attributes
    ----------
    substructures : Substructures
    rig_params : dict of str to dict
        Rig name -> its resolved parameters, in the order of the structure's rigs (the
        study's rig ``''``: the run's parameters).
    """

    substructures: Substructures
    rig_params: dict

    @property
    def structure(self) -> Structure:
        """The :class:`Structure`."""
        return self.substructures.structure

    @property
    def rig_names(self) -> tuple:
        """The rigs, in the structure's order of its physical DOFs."""
        return self.substructures.structure.rig_names

    @property
    def is_study(self) -> bool:
        """Whether this is the reference study's test (its one rig in the root
        namespace)."""
        return self.rig_names == (STUDY_RIG,)


def test_setup(params: Mapping[str, Any]) -> TestSetup:
    """The :class:`TestSetup` of a run: its structure split against its rigs' specimens.

    The study's test (no ``structure``) is the one-DOF structure of :func:`study_structure`
    whose rig has the run's parameters and whose mass ratio is the run's ``alpha`` exactly.

    Raises
    ------
    ParameterError
        An invalid structure, or a rig whose parameters disagree with it.
    """
    structure = structure_of(params)
    if is_study(params):
        rig_params = {STUDY_RIG: dict(params)}
        return TestSetup(split(structure, rig_params, study_alpha=float(params['alpha'])),
                         rig_params)
    rig_params = {r: rig_parameters(params, structure, r) for r in structure.rig_names}
    return TestSetup(split(structure, rig_params), rig_params)


#: Not tests, whatever their names (pytest collects ``test*`` names a test module imports).
TestSetup.__test__ = False
test_setup.__test__ = False


def reduces_to_study(sub: Substructures) -> bool:
    """Whether the structure is the reference study's test: one physical DOF, nothing
    computational but a rigid mass on it (then it runs as the study's single rig, bit for
    bit, with ``alpha = mu / m``)."""
    return sub.structure.n == 1 and not sub.coupled


def study_parameters(params: Mapping[str, Any], sub: Substructures) -> dict[str, Any]:
    """The flat parameters of the study's test for a structure that :func:`reduces_to_study`:
    the rig's parameters, ``alpha = mu / m`` and no structure.

    Raises
    ------
    ParameterError
        The structure does not reduce, or the run sets ``alpha`` too.
    """
    if not reduces_to_study(sub):
        raise ParameterError('structure: not a single rig with a rigid mass')
    if float(params.get('alpha', 0.0)) != 0.0:
        raise ParameterError(f'parameter alpha={params["alpha"]!r}: with a structure the '
                             "computational mass is the structure's (its mass at the physical "
                             'dof); leave alpha at 0')
    rig = sub.structure.rig_names[0]
    out = rig_parameters(params, sub.structure, rig)
    out['alpha'] = float(sub.alpha[0])
    out['structure'] = NO_STRUCTURE
    return out
