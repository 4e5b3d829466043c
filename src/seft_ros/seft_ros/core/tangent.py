"""The stiffness a yielding computational part is predicted with over the loop delay (no
rclpy).

The compensators predict the interface force of the computational part over the loop delay
with a linear model (:class:`~seft_ros.core.substructure.InterfacePredictor`). A model that
yields (an OpenSees frame) gives its tangent stiffness ``K_t`` at each sample
(``ComputationalPart.tangent``); held over the prediction it is right while its members go
on yielding, and wrong where one unloads (it is elastic again: ``K_0``) or starts to yield
(it softens before its tangent shows it). :class:`YieldMechanisms` follows the model's own
samples and gives the stiffness for the predicted motion:

* the **deficit** ``D = K_0 - K_t`` (symmetric, positive semi-definite where members yield)
  is split into yielding mechanisms ``u_i`` (``D = sum lambda_i u_i u_i^T``), each with the
  coordinate ``z_i = u_i . x``: first over the directions of the mechanisms found before the
  test (below), each keeping its own (``lambda_i >= 0`` by non-negative least squares over
  the matrix's entries; the gradual ones only while those directions give the deficit to
  :data:`KNOWN_RESIDUAL`), then what they do not give into its eigen-directions. Two members
  whose directions are not orthogonal (two stories that share a floor: ``u . u' = -1/2``)
  yielding together have eigenvectors that mix them, matching neither;
* a mechanism **goes on yielding** if the predicted increment of ``z_i`` has the sense of
  its last one, and **unloads** otherwise (its deficit given back: the loading/unloading
  condition of plasticity);
* a mechanism that goes on yielding while its deficit **grows** (a member that yields
  gradually: a ``Steel02`` story) takes, over the predicted increment ``dz``, its mean
  deficit ``lambda + s dz / 2`` (the trapezoid), ``s = d lambda / dz`` between the last two
  tangents the part read in that yielding: the tangent held over the prediction is the
  one the member had a few samples before. Only for a mechanism whose direction stays
  (:data:`STEADY_DIRECTION`): one member, its deficit a function of its coordinate alone.
  Measured (``config/opensees/shear_frame.py`` with a ``Steel02`` story 2, ``model``,
  four records at drift ductilities 2.1-9.1): the worst floor's NRMS x 1.57-3.47 % with
  the tangent held, 0.67-1.42 % so; a fibre frame's column mechanisms turn their
  directions from sample to sample (the steel frame, El Centro 1940 at 2600 N: followed on
  every yielding mechanism, floor-1 x 17.3 %, with a 1e-6 turn allowed 4.96 %, against
  3.49 % without);
* a mechanism whose sample reversed its motion on a **held tangent** (the part did not read
  its tangent again: the same matrix as the sample before, read before the reversal) unloads:
  that tangent cannot show the reversal. A model steps a reversal on one Newton solve where
  the increment is small, and keeps the tangent it read last (``OpenSeesPart``); taken as
  yielding in the new sense, the mechanism's stiffness went from ``K_0`` to the held tangent
  and back over two samples, and the interface force predicted with it stepped by up to
  2.6 kN (the steel frame at ``M/M_y`` 1.35 on El Centro 1940: NRMS x 3.67 % with
  ``model``, ``adaptive`` unstable; with the held reversal unloading 3.04 % and 2.94 %);
* an elastic mechanism seen yielding before **starts to yield again** where its coordinate
  passes the point where it last stopped (the same sense) or that point less its elastic
  range (the other sense): the part of the predicted increment beyond that point is taken
  with the deficit its last onset showed (a stiffness ``K_0 - phi lambda_onset u u^T``,
  ``phi`` that part: all of its deficit for a bilinear member, little for one that yields
  gradually). The elastic range is the one it has shown between yielding in one sense and
  the other (learnt at its first reversal) or, before that, for a **sharp** mechanism (its
  first yielding bilinear), twice the distance from rest of its first onset (Masing: a
  kinematically hardening member starts at rest in the middle of its elastic range, and
  keeps the range's width);
* a mechanism **found before the test** (:class:`VirginMechanism`: an OpenSees part's
  pushover, :func:`seft_ros.opensees.probe.probe_yield`) and bilinear there starts to yield,
  before it ever has, where its virgin elastic range ends in the predicted sense (its first
  yield anticipated), and takes that range's width as its elastic range until a reversal
  shows it (in place of Masing's from its first onset);
* a mechanism the pushover found (one bilinear member) has its **onset** (the first yielding
  sample of an episode) and **end** placed by its share of the part's **deficit force**
  ``K_0 x - R(x)`` where it gives it (an OpenSees part: ``deficit_forces``, from its
  equation of motion): for such a mechanism it grows as ``lambda (z - z_onset)`` from its
  value when the mechanism was last elastic, which places the onset within its step (up to
  :data:`ONSET_STEPS` steps back), and an episode's end where the travel turned between its
  samples. The share is the mechanism's coordinate in the deficit force's least-squares
  split over those directions (its projection on its own direction also holds the others'
  where they are not orthogonal: a frame with two such stories yielding, on the default
  record at 2500 / 1500 N, floor-3 NRMS x 11.91 % with the eigenvectors and the projection,
  0.65 % so). Other mechanisms' deficit forces can share a direction (the steel frame's
  fibre columns: with every bilinear episode so placed, floor-1 NRMS x on El Centro 1940 at
  2600 N 7.49 % against 3.49 %; with the sharp ones, 3.75 %), so a sharp mechanism the
  pushover did not find has its onset taken at the middle of the step that shows it
  (:data:`ONSET_FRACTION`; the sample is past the onset by an unknown part of the step's
  increment, about ``k v dt`` of force: 60 N of a 210 kN/m story at 0.15 m/s and 2 ms), and
  an episode's end at its last yielding sample. A mechanism whose first yielding was gradual
  (a ``Steel02`` fibre section: its first deficit is small, and grows) keeps the range it
  has shown, from the samples (measured, the steel frame on El Centro 1940 at ``M/M_y``
  1.35, ``model``: floor-1 NRMS x 5.59 % with both for every bilinear mechanism, 3.49 % with
  them for the sharp ones only, 3.72 % with neither).

Exact for one bilinear member with kinematic hardening (a ``Steel01``), with the deficit
force (without it, for one whose onset and reversal fall on the samples); for gradual
yielding (``Steel02`` fibres) the tangent itself follows the curve from sample to sample.
Several members whose directions are not orthogonal, and that the pushover did not find,
share their eigen-directions.

References
----------
J. C. Simo and T. J. R. Hughes (1998), Computational Inelasticity, Springer, Secs. 1.2-1.4
(the loading/unloading conditions, the elastic predictor); G. Masing (1926), the elastic range
of a kinematically hardening member is twice its yield strength, whatever its history;
C. L. Lawson and R. J. Hanson (1974), Solving Least Squares Problems, Prentice-Hall, Ch. 23
(non-negative least squares: ``scipy.optimize.nnls``).
"""

from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

__all__ = ['YieldMechanisms', 'Mechanism', 'VirginMechanism', 'DEFICIT_TOLERANCE',
           'SAME_DIRECTION', 'BILINEAR_SPREAD', 'ONSET_FRACTION', 'ONSET_STEPS',
           'STEADY_DIRECTION', 'SLOPE_TRAVEL_M', 'SOFTENING_LIMIT', 'KNOWN_RESIDUAL']

#: A deficit of the tangent stiffness below this part of the largest entry of the initial one
#: is no yielding.
DEFICIT_TOLERANCE = 1e-3
#: Two deficit directions with ``|u . u'|`` above this are one mechanism.
SAME_DIRECTION = 0.95
#: A yielding whose deficit stayed within this part of its largest is bilinear.
BILINEAR_SPREAD = 0.1
#: An onset is taken this far back along the increment of the step that shows it (0: at
#: the sample; 0.5: the middle of the step, where an onset anywhere in it is expected).
#: Measured (the shear frame, Steel01 story, ``model``, ductility 2.5): the rig's
#: acceleration NRMS on El Centro 1940 3.44 % at 0, 3.01 % at 0.5; Kobe KJMA 090 3.14 and
#: 2.41 % (Masing's range in both; before either, 4.29 and 4.24 %).
ONSET_FRACTION = 0.5
#: An onset placed by the deficit force lies at most this many steps of its sample's
#: increment back (a tangent the part read a sample late shows an onset of the step before).
ONSET_STEPS = 3.0
#: A mechanism whose direction turned by less than this between two samples
#: (``1 - |u . u'|``) is one member's, whose deficit is a function of its coordinate alone:
#: its slope is followed over the predicted increment (module notes). The eigenvector of one
#: member's rank-one deficit keeps its direction to rounding (1e-15); a fibre frame's
#: columns, yielding together, turn theirs by 1e-6 and more from sample to sample.
STEADY_DIRECTION = 1e-10
#: The least travel [m] between two tangents read over which a slope is measured (below, the
#: tangents' rounding would make it).
SLOPE_TRAVEL_M = 1e-9
#: The gradual members the pushover found (``Steel02``) are split out of the deficit only
#: while their directions give it to within this part (Frobenius norm): one member's
#: deficit is one rank-one term along its direction; a fibre frame's columns' is not (the
#: steel frame, El Centro 1940 at 2600 N: split out regardless, floor-1 NRMS x 11.5 %
#: against 3.49 %).
KNOWN_RESIDUAL = 0.01
#: A member that softens on over the prediction loses at most this part of the stiffness it
#: has left along its direction (its slope, extrapolated from the start of a branch, can
#: be far steeper than the branch: a `Steel02` story's reloading; removed whole, the
#: computational DOFs' stiffness was singular).
SOFTENING_LIMIT = 0.5


@dataclass
class Mechanism:
    """One yielding mechanism as seen so far.

    Attributes
    ----------
    direction : ndarray (n,)
        ``u`` (unit).
    deficit_N_per_m : float
        ``lambda`` when it last yielded.
    sense : float
        +1 or -1: the sense of ``z = u . x`` in which it last yielded.
    yielding : bool
        Whether it yields at the latest sample.
    stop_m : float or None
        ``z`` where it last stopped yielding (None: it yields, or never stopped).
    last_m : float
        ``z`` at the latest sample.
    elastic_range_m : float or None
        The range of ``z`` it has shown elastic between yielding in one sense and the other
        (None: not seen yet).
    onset_deficit_N_per_m : float
        ``lambda`` at the first sample of its latest yielding: the softening its onset
        brings.
    episode_N_per_m : list of float
        The least and the largest ``lambda`` of its latest yielding.
    bilinear : bool
        Whether its latest finished yielding kept one deficit (within
        :data:`BILINEAR_SPREAD`): a member whose onset is sharp and whose elastic range is
        fixed (a ``Steel01``); only such a mechanism's onset is anticipated.
    held_reversal : bool
        Whether the latest sample reversed its motion (it yielded in the other sense at the
        sample before) on a tangent the part held from before the reversal: it unloads.
    first_onset_m : float or None
        ``z`` of its first onset (:data:`ONSET_FRACTION`), in the direction it was first
        seen in; for a sharp mechanism twice its distance from rest is its elastic range
        until a reversal shows it (Masing).
    sharp : bool or None
        Whether its first yielding was bilinear (None: it has not ended yet).
    slope_N_per_m2 : float
        ``d lambda / dz`` (>= 0) over its latest yielding, between the last two tangents the
        part read, while its direction stays (:data:`STEADY_DIRECTION`); 0 otherwise.
    read : tuple of float or None
        ``(z, lambda)`` at the last tangent read in its latest yielding.
    """

    direction: np.ndarray
    deficit_N_per_m: float
    sense: float
    yielding: bool = True
    stop_m: float | None = None
    last_m: float = 0.0
    elastic_range_m: float | None = None
    onset_deficit_N_per_m: float = 0.0
    episode_N_per_m: list = None
    bilinear: bool = False
    held_reversal: bool = False
    first_onset_m: float | None = None
    sharp: bool | None = None
    virgin_range_m: tuple | None = None
    reference_N: float | None = None
    onset_m: float | None = None
    slope_N_per_m2: float = 0.0
    read: tuple | None = None


@dataclass(frozen=True)
class VirginMechanism:
    """A mechanism the computational part found before the test, before it ever yielded (an
    OpenSees part's pushover: :func:`seft_ros.opensees.probe.probe_yield`).

    Attributes
    ----------
    direction : ndarray (n,)
        ``u`` (unit).
    deficit_N_per_m : float
        ``lambda`` once it yields.
    low_m, high_m : float or None
        Its virgin elastic range ``[z_low, z_high]`` of ``z = u . x`` [m]: where it first
        yields in the negative and the positive sense (None: not found).
    bilinear : bool
        Whether it yields sharply, keeping its deficit (only such a mechanism's onset is
        anticipated).
    """

    direction: np.ndarray
    deficit_N_per_m: float
    low_m: float | None
    high_m: float | None
    bilinear: bool


class YieldMechanisms:
    """A computational part's yielding mechanisms and the stiffness for a predicted motion.

    Parameters
    ----------
    initial_N_per_m : ndarray (n, n)
        ``K_0``: the computational part's initial (linearization's) stiffness [N/m].
    known : sequence of VirginMechanism
        Mechanisms found before the test: each keeps its direction and its deficit split
        from the others' (a gradual one while the split holds: :data:`KNOWN_RESIDUAL`); a
        bilinear one's first yield is anticipated where its virgin elastic range ends, and
        its onsets placed by its share of the deficit force (module notes).
    free_dofs : sequence of int
        The computational DOFs (the part's ``K_UU`` must stay regular: a member that
        softens on over the prediction keeps :data:`SOFTENING_LIMIT` of what it has left;
        none given: what ``u^T K u`` has left).

    Attributes
    ----------
    mechanisms : list of Mechanism
    """

    def __init__(self, initial_N_per_m, known=(), free_dofs=()):
        self.k0 = np.asarray(initial_N_per_m, dtype=float)
        self._free = [int(i) for i in free_dofs]
        self._free_block = np.ix_(self._free, self._free)
        self.scale = float(np.max(np.abs(self.k0)))
        self.mechanisms: list[Mechanism] = []
        self._last_x = None
        self._tangent = None
        for v in known:
            u = np.asarray(v.direction, dtype=float)
            u = u / np.linalg.norm(u)
            if v.bilinear and (v.low_m is not None or v.high_m is not None):
                self.mechanisms.append(Mechanism(
                    u, float(v.deficit_N_per_m), 1.0, yielding=False,
                    onset_deficit_N_per_m=float(v.deficit_N_per_m), bilinear=True,
                    sharp=True, virgin_range_m=(v.low_m, v.high_m), reference_N=0.0))
            elif not v.bilinear:
                # a gradual member: its direction kept, nothing anticipated (module notes)
                self.mechanisms.append(Mechanism(u, float(v.deficit_N_per_m), 1.0,
                                                 yielding=False, reference_N=0.0))
        # the pushover's mechanisms keep their directions (module notes); their split's
        # matrices, made once
        self._known = list(self.mechanisms)
        self._basis = (np.stack([np.outer(m.direction, m.direction).ravel()
                                 for m in self._known], axis=1) if self._known else None)
        self._directions = (np.stack([m.direction for m in self._known], axis=1)
                            if self._known else None)
        self._split = None                # the latest tangent's split (kept while held)

    @property
    def uses_deficit(self) -> bool:
        """Whether :meth:`observe` uses the part's deficit force: only for the mechanisms
        the pushover found (module notes); without one, the part need not compute it."""
        return any(m.virgin_range_m is not None for m in self.mechanisms)

    def observe(self, x_m, tangent_N_per_m, deficit_N=None) -> None:
        """Take a sample: every DOF's displacement [m], the tangent (None: the initial
        one: nothing yields) and, if the part gives it, its restoring force short of the
        initial stiffness's, ``K_0 x - R(x)`` [N] (n,; None: an onset is placed at
        :data:`ONSET_FRACTION` of its step, an episode's end at its last yielding
        sample)."""
        x = np.asarray(x_m, dtype=float)
        dx = x - self._last_x if self._last_x is not None else np.zeros_like(x)
        self._last_x = x
        forces = None if deficit_N is None else np.asarray(deficit_N, dtype=float)
        previous = self._tangent
        self._tangent = None if tangent_N_per_m is None else np.asarray(tangent_N_per_m,
                                                                        dtype=float)
        held = (previous is not None and self._tangent is not None
                and np.array_equal(previous, self._tangent))
        seen = set()
        shares = self._shares(forces)
        if self._tangent is not None:
            if not held or self._split is None:
                # (a held tangent splits as before: the same matrix)
                deficit = self.k0 - self._tangent
                deficit = 0.5 * (deficit + deficit.T)
                known_found, rest = self._known_yielding(deficit)
                self._split = (known_found,) + tuple(np.linalg.eigh(rest))
            known_found, lam, u = self._split
            found = list(known_found)
            for i in np.nonzero(lam > DEFICIT_TOLERANCE * self.scale)[0]:
                found.append((self._match(u[:, i]), u[:, i], float(lam[i])))
            for m, ui, lam_i in found:
                dz = float(ui @ dx)
                if m is None:
                    # its first yielding: the part was linear before (no deficit force)
                    m = Mechanism(ui.copy(), lam_i, 1.0 if dz >= 0.0 else -1.0,
                                  yielding=False, reference_N=0.0)
                    self.mechanisms.append(m)
                elif float(m.direction @ ui) < 0.0:
                    ui, dz = -ui, -dz
                sense = 1.0 if dz >= 0.0 else -1.0
                self._follow_slope(m, ui, float(ui @ x), lam_i, sense, held)
                if not m.yielding or m.episode_N_per_m is None:
                    m.onset_deficit_N_per_m = lam_i
                    m.episode_N_per_m = [lam_i, lam_i]
                    # placed by its share of the deficit force if the pushover found the
                    # mechanism one bilinear member (module notes)
                    m.onset_m = float(ui @ x) - self._onset_back(
                        dz, lam_i, shares.get(id(m)), m.reference_N)
                    if m.first_onset_m is None:
                        m.first_onset_m = m.onset_m
                    if m.stop_m is not None and sense != m.sense:
                        # yielding again in the other sense: the elastic range it has shown
                        m.elastic_range_m = abs((m.onset_m if m.sharp else float(ui @ x))
                                                - m.stop_m)
                m.episode_N_per_m = [min(m.episode_N_per_m[0], lam_i),
                                     max(m.episode_N_per_m[1], lam_i)]
                # (m still holds the sample before's state; a new one yields in `sense`)
                m.held_reversal = held and m.yielding and m.sense != sense
                m.direction, m.deficit_N_per_m, m.sense, m.yielding = ui, lam_i, sense, True
                seen.add(id(m))
        for m in self.mechanisms:
            z = float(m.direction @ x)
            if id(m) not in seen:
                m.held_reversal = False
                if m.yielding:
                    m.yielding, m.stop_m = False, m.last_m
                    low, high = m.episode_N_per_m
                    m.bilinear = low >= (1.0 - BILINEAR_SPREAD) * high
                    if m.sharp is None:
                        m.sharp = m.bilinear
                    held_N = shares.get(id(m))
                    if m.bilinear and m.virgin_range_m is not None:
                        m.stop_m = self._stop(m, held_N)
                    m.reference_N = held_N
            m.last_m = z

    @staticmethod
    def _follow_slope(m: 'Mechanism', u, z_m: float, lam: float, sense: float,
                      held: bool) -> None:
        """Update the slope of a yielding mechanism's deficit along its coordinate from the
        tangent the part read at this sample (`u`, ``z``, ``lambda``; module notes): kept
        on a held tangent, 0 where the mechanism starts or reverses its yielding, turns
        its direction, or did not travel on in its sense."""
        steady = abs(float(m.direction @ u)) > 1.0 - STEADY_DIRECTION
        if not (m.yielding and m.sense == sense and steady and m.read is not None):
            m.slope_N_per_m2, m.read = 0.0, (z_m, lam)
            return
        if held:
            return
        travel = sense * (z_m - m.read[0])
        m.slope_N_per_m2 = (max((lam - m.read[1]) / travel, 0.0) if travel > SLOPE_TRAVEL_M
                            else 0.0)
        m.read = (z_m, lam)

    @staticmethod
    def _onset_back(dz: float, deficit_N_per_m: float, share_N, reference_N) -> float:
        """How far back from the sample along its direction [m] an onset lies that the
        sample's step (increment `dz` [m]) shows: where the growth of the mechanism's share
        of the deficit force (`share_N`, None: not known) since it was last elastic
        (`reference_N`), ``lambda (z - z_onset)``, puts it (exact for a bilinear member; up
        to :data:`ONSET_STEPS` steps back: a tangent read a sample late), else
        :data:`ONSET_FRACTION` of the step."""
        if share_N is not None and reference_N is not None and dz != 0.0:
            beyond = (share_N - reference_N) / deficit_N_per_m
            if 0.0 <= beyond / dz <= ONSET_STEPS:
                return beyond
        return ONSET_FRACTION * dz

    def _known_yielding(self, deficit):
        """The deficit split over the directions the pushover found (module notes):
        ``D = sum_j lambda_j u_j u_j^T + rest`` with ``lambda_j >= 0`` by non-negative least
        squares over the matrix's entries (scipy.optimize.nnls).

        Returns
        -------
        found : list of (Mechanism, ndarray (n,), float)
            The known mechanisms that yield (``lambda_j`` above :data:`DEFICIT_TOLERANCE`),
            each with its direction and ``lambda_j`` [N/m].
        rest : ndarray (n, n)
            What the known directions do not give [N/m] (the other mechanisms' deficit).
        """
        known = self._known
        if not known:
            return [], deficit
        basis = self._basis
        lam, _ = nnls(basis, deficit.ravel())
        rest = deficit - (basis @ lam).reshape(deficit.shape)
        if np.linalg.norm(rest) > KNOWN_RESIDUAL * np.linalg.norm(deficit):
            # the gradual members' directions do not give it: the bilinear ones alone
            bilinear = [m.virgin_range_m is not None for m in known]
            if not any(bilinear):
                return [], deficit
            lam = np.where(bilinear, lam, 0.0)
            if not all(bilinear):
                sub = basis[:, bilinear]
                lam[np.nonzero(bilinear)[0]] = nnls(sub, deficit.ravel())[0]
                rest = deficit - (basis @ lam).reshape(deficit.shape)
        found = [(m, m.direction, float(lam_j)) for m, lam_j in zip(known, lam)
                 if lam_j > DEFICIT_TOLERANCE * self.scale]
        return found, rest

    def _shares(self, forces) -> dict:
        """Each known bilinear mechanism's share of the deficit force ``K_0 x - R(x)`` [N]
        (`forces`, (n,); None: none; only theirs place onsets): its coordinate in the
        force's least-squares split over all the known directions (``F = sum_j s_j u_j``).
        Along a mechanism's own direction the force also carries the others' shares where
        the directions are not orthogonal (two adjacent stories: ``u . u' = -1/2``). Keyed by
        the mechanism's ``id``."""
        if forces is None or not self._known:
            return {}
        s = np.linalg.lstsq(self._directions, forces, rcond=None)[0]
        return {id(m): float(v) for m, v in zip(self._known, s)
                if m.virgin_range_m is not None}

    @staticmethod
    def _stop(m: 'Mechanism', held_N: float | None) -> float:
        """Where a bilinear mechanism's yielding episode stopped [m] (along its direction):
        its onset plus the deficit force it gained over the episode over its deficit
        stiffness (the extreme of its travel, between samples), or the last sample that
        yielded without the deficit forces."""
        if held_N is None or m.reference_N is None or m.onset_m is None:
            return m.last_m
        stop = m.onset_m + (held_N - m.reference_N) / float(np.mean(m.episode_N_per_m))
        # the extreme lies past the last yielding sample, by less than a few of its steps
        if m.sense * (stop - m.last_m) >= -1e-3 * abs(stop - m.onset_m):
            return stop
        return m.last_m

    def _remaining(self, k, u) -> float:
        """The stiffness [N/m] along `u` that `k` keeps with the computational DOFs free
        (``1 / (u_U^T K_UU^-1 u_U)``; a story: its own stiffness along ``u``, the other
        members' held by the interface): what may soften before ``K_UU`` is singular
        (``u^T k u`` where `u` moves no free DOF or none are given; 0 where ``K_UU`` is
        singular already)."""
        free = self._free
        if not free:
            return float(u @ k @ u)
        u_free = u[free]
        if not u_free.any():
            return float(u @ k @ u)
        try:
            flexibility = float(u_free @ np.linalg.solve(k[self._free_block], u_free))
        except np.linalg.LinAlgError:
            return 0.0
        return 1.0 / flexibility if flexibility > 0.0 else 0.0

    def _match(self, u) -> 'Mechanism | None':
        best, score = None, SAME_DIRECTION
        for m in self.mechanisms:
            if any(m is k for k in self._known):
                continue
            s = abs(float(m.direction @ u))
            if s > score:
                best, score = m, s
        return best

    def stiffness(self, predicted_increment_m) -> np.ndarray | None:
        """The stiffness to predict with for the predicted increment of every DOF's
        displacement over the prediction [m] (None: no mechanism changes from the latest
        sample's tangent; module notes).

        Returns
        -------
        ndarray (n, n) or None
        """
        if not self.mechanisms:
            return None
        dx = np.asarray(predicted_increment_m, dtype=float)
        k = self.k0.copy() if self._tangent is None else self._tangent.copy()
        changed = False
        for m in self.mechanisms:
            u, dz = m.direction, float(m.direction @ dx)
            if m.yielding:
                if m.held_reversal or dz * m.sense <= 0.0:    # it unloads: elastic again
                    k += m.deficit_N_per_m * np.outer(u, u)
                    changed = True
                elif m.slope_N_per_m2 > 0.0:
                    # it goes on softening: its mean deficit over the increment (module
                    # notes), losing at most SOFTENING_LIMIT of what it has left along u
                    more = min(0.5 * m.slope_N_per_m2 * abs(dz),
                               SOFTENING_LIMIT * self._remaining(k, u))
                    if more > 0.0:
                        k -= more * np.outer(u, u)
                        changed = True
                continue
            if dz == 0.0 or not m.bilinear:
                continue
            sense = 1.0 if dz > 0.0 else -1.0
            virgin = m.virgin_range_m
            if m.stop_m is None:
                # never yielded: where the pushover found it yields (module notes)
                onset = None if virgin is None else virgin[1] if sense > 0.0 else virgin[0]
                if onset is None:
                    continue
            elif sense == m.sense:
                onset = m.stop_m
            elif m.elastic_range_m is not None:
                onset = m.stop_m - m.sense * m.elastic_range_m
            elif virgin is not None and None not in virgin:
                onset = m.stop_m - m.sense * (virgin[1] - virgin[0])
            elif m.sharp:                         # Masing, before its first reversal
                onset = m.stop_m - m.sense * 2.0 * abs(m.first_onset_m)
            else:
                continue
            beyond = sense * (m.last_m + dz - onset)
            if beyond > 0.0 and sense * (onset - m.last_m) >= 0.0:
                k -= min(beyond / abs(dz), 1.0) * m.onset_deficit_N_per_m * np.outer(u, u)
                changed = True
        return k if changed else None
