"""The stiffness a yielding computational part is predicted with (issue 40,
:mod:`seft_ros.core.tangent`): a bilinear story between two floors, followed sample by
sample, against the loading/unloading conditions worked out by hand."""

import numpy as np
import pytest

from seft_ros.core.tangent import VirginMechanism, YieldMechanisms

K = 2.11e5                                   # each story's initial stiffness [N/m]
B = 0.02                                     # story 2's post-yield ratio
#: two floors: story 1 to the ground, story 2 between them (its deformation z ~ x2 - x1)
K0 = np.array([[2 * K, -K], [-K, K]])
U = np.array([-1.0, 1.0]) / np.sqrt(2.0)     # story 2's mechanism
LAM = (1 - B) * K * 2.0                      # its deficit along U when it yields


def yielded():
    return K0 - LAM * np.outer(U, U)


@pytest.fixture
def loaded():
    """Story 2 loaded elastically, then yielding in the + sense for two samples."""
    m = YieldMechanisms(K0)
    for x2 in (0.0, 0.004, 0.008):
        m.observe([0.0, x2], None)
    for x2 in (0.012, 0.016):
        m.observe([0.0, x2], yielded())
    return m


def test_nothing_yields_nothing_changes():
    m = YieldMechanisms(K0)
    m.observe([0.0, 0.0], None)
    m.observe([0.001, 0.002], None)
    assert m.stiffness([0.0, 0.003]) is None and m.mechanisms == []


def test_a_yielding_mechanism_goes_on_or_unloads(loaded):
    (mech,) = loaded.mechanisms
    assert mech.yielding and mech.sense == pytest.approx(np.sign(U @ [0.0, 1.0]))
    assert mech.deficit_N_per_m == pytest.approx(LAM)
    assert loaded.stiffness([0.0, 0.002]) is None          # goes on: its tangent holds
    np.testing.assert_allclose(loaded.stiffness([0.0, -0.002]), K0, rtol=1e-12)  # unloads


def test_a_reversal_on_a_held_tangent_unloads(loaded):
    """A sample that reversed the motion on the tangent read before the reversal (the part
    held it: the same matrix) unloads whatever the predicted increment; a tangent read
    again that still shows the deficit yields in the new sense."""
    held = loaded.mechanisms[0]
    loaded.observe([0.0, 0.0155], yielded())               # reversed, the tangent held
    assert held.yielding and held.held_reversal
    assert held.sense == pytest.approx(-np.sign(U @ [0.0, 1.0]))
    for increment in ([0.0, -0.002], [0.0, 0.002]):
        np.testing.assert_allclose(loaded.stiffness(increment), K0, rtol=1e-12)
    loaded.observe([0.0, 0.015], yielded())                # goes on back: not a reversal
    assert not held.held_reversal
    assert loaded.stiffness([0.0, -0.002]) is None         # the held tangent, as before

    fresh = YieldMechanisms(K0)                            # the same motion, read again
    for x2 in (0.0, 0.004, 0.008):
        fresh.observe([0.0, x2], None)
    for x2, ratio in ((0.012, 1.0), (0.016, 1.0), (0.0155, 0.9)):
        fresh.observe([0.0, x2], K0 - ratio * LAM * np.outer(U, U))
    (mech,) = fresh.mechanisms
    assert mech.yielding and not mech.held_reversal
    assert fresh.stiffness([0.0, -0.002]) is None          # yields on in the new sense
    np.testing.assert_allclose(fresh.stiffness([0.0, 0.002]), K0, rtol=1e-12)  # unloads


def test_onset_is_anticipated_where_it_stopped_and_after_its_elastic_range(loaded):
    z = lambda x2: float(U @ [0.0, x2])                    # noqa: E731
    for x2 in (0.012, 0.008):                              # unloads elastically
        loaded.observe([0.0, x2], None)
    (mech,) = loaded.mechanisms
    assert not mech.yielding and mech.stop_m == pytest.approx(z(0.016))
    assert mech.bilinear
    # reloading in the same sense: it yields again past z(0.016), a quarter of the increment
    k = loaded.stiffness([0.0, 0.0107])         # from 0.008 to 0.0187: 0.0027 of 0.0107 past
    np.testing.assert_allclose(k, K0 - (0.0027 / 0.0107) * LAM * np.outer(U, U), rtol=1e-9)
    assert loaded.stiffness([0.0, 0.004]) is None          # not far enough
    # the other sense, before it has yielded there: Masing's range, twice its first onset's
    # distance from rest; that onset is the middle of the step that showed it (0.008 to
    # 0.012): x2 = 0.010, so it yields again at x2 = 0.016 - 0.020 = -0.004
    assert mech.first_onset_m == pytest.approx(z(0.010))
    k = loaded.stiffness([0.0, -0.016])                    # to -0.008: 0.004 of 0.016 past
    np.testing.assert_allclose(k, K0 - 0.25 * LAM * np.outer(U, U), rtol=1e-9)
    assert loaded.stiffness([0.0, -0.011]) is None         # to -0.003: not far enough
    for x2 in (0.0, -0.008):                               # elastic, then yields in - at -0.008
        loaded.observe([0.0, x2], None if x2 > -0.008 else yielded())
    # the range it has shown: from z(0.016) to the middle of the step 0.0 -> -0.008
    assert mech.elastic_range_m == pytest.approx(abs(z(-0.004) - z(0.016)))
    for x2 in (-0.012, -0.004):                            # yields, then unloads
        loaded.observe([0.0, x2], yielded() if x2 < -0.008 else None)
    # back in +: it yields again at z(-0.012) + its elastic range, at x2 = 0.008
    k = loaded.stiffness([0.0, 0.020])                     # to 0.016: 0.008 of 0.020 past
    np.testing.assert_allclose(k, K0 - 0.4 * LAM * np.outer(U, U), rtol=1e-9)


def test_a_gradual_yielding_is_not_anticipated():
    m = YieldMechanisms(K0)
    m.observe([0.0, 0.0], None)
    for x2, share in ((0.004, 0.2), (0.008, 0.5), (0.012, 0.9)):   # the deficit grows
        m.observe([0.0, x2], K0 - share * LAM * np.outer(U, U))
    m.observe([0.0, 0.010], None)
    (mech,) = m.mechanisms
    assert not mech.bilinear
    assert m.stiffness([0.0, 0.01]) is None


def test_a_first_yield_the_pushover_found_is_anticipated():
    """A mechanism found before the test (its virgin elastic range: an asymmetric one, -6 to
    +10 mm of z) starts to yield where that range ends, in either sense, before it has ever
    yielded; once it has, in the other sense after the range's width (kinematic hardening);
    a gradual one found so is not anticipated."""
    low, high = -0.006, 0.010
    m = YieldMechanisms(K0, [VirginMechanism(U, LAM, low, high, True),
                             VirginMechanism(np.array([1.0, 0.0]), LAM, -0.001, 0.001, False)])
    mech, gradual = m.mechanisms                 # the gradual one kept, never anticipated
    assert gradual.virgin_range_m is None and not gradual.bilinear
    x2 = lambda z: z * np.sqrt(2.0)                          # noqa: E731 (x1 held at 0)
    m.observe([0.0, 0.0], None)
    m.observe([0.0, x2(0.004)], None)
    assert m.stiffness([0.0, x2(0.004)]) is None             # to z 0.008: within the range
    # to z 0.014: 0.004 of the 0.010 increment past the onset at +0.010
    np.testing.assert_allclose(m.stiffness([0.0, x2(0.010)]),
                               K0 - 0.4 * LAM * np.outer(U, U), rtol=1e-9)
    # to z -0.008 (the other sense): 0.002 of the 0.012 increment past -0.006
    np.testing.assert_allclose(m.stiffness([0.0, x2(-0.012)]),
                               K0 - (0.002 / 0.012) * LAM * np.outer(U, U), rtol=1e-9)
    for z in (0.008, 0.012, 0.016):                          # yields in + from 0.010
        m.observe([0.0, x2(z)], None if z < high else yielded())
    m.observe([0.0, x2(0.014)], None)                        # stops at 0.016, unloads
    assert not mech.yielding and mech.stop_m == pytest.approx(0.016)
    assert gradual.stop_m is None and len(m.mechanisms) == 2  # it never yielded
    # back in -: it yields again at 0.016 - 0.016 (the range's width) = 0.0
    np.testing.assert_allclose(m.stiffness([0.0, x2(-0.018)]),
                               K0 - (0.004 / 0.018) * LAM * np.outer(U, U), rtol=1e-9)
    assert m.stiffness([0.0, x2(-0.012)]) is None            # to z 0.002: not yet


def test_onsets_and_ends_placed_by_the_deficit_force():
    """For a mechanism the pushover found (one bilinear member: story 2, yielding at z
    +-0.0105), the part's deficit force (``K_0 x - R``: ``LAM (z - z_y) U`` while it yields
    past its onset z_y, held at its value once it unloads) places an onset where it is, not
    at the middle of its step, and an episode's end at the extreme of its travel between
    samples: the onset 0.0105 (the middle of the step: 0.010), the end 0.0165 (the last
    yielding sample: 0.016); the other sense is then anticipated at 0.0165 - 0.021 (the
    virgin range's width) = -0.0045. A mechanism the pushover did not find keeps the middle
    of the step and the last yielding sample, deficit force or not (several members'
    deficits can share one direction: the steel frame's fibre columns)."""
    x2 = lambda z: z * np.sqrt(2.0)                          # noqa: E731 (x1 held at 0)
    force = lambda beyond: LAM * beyond * U                  # noqa: E731
    samples = ((0.0, None, 0.0), (0.008, None, 0.0), (0.012, yielded(), 0.012 - 0.0105),
               (0.016, yielded(), 0.016 - 0.0105), (0.015, None, 0.0165 - 0.0105))
    m = YieldMechanisms(K0, [VirginMechanism(U, LAM, -0.0105, 0.0105, True)])
    for z, k, beyond in samples[:3]:
        m.observe([0.0, x2(z)], k, force(beyond))
    (mech,) = m.mechanisms
    assert mech.first_onset_m == pytest.approx(0.0105, rel=1e-12)
    for z, k, beyond in samples[3:]:
        m.observe([0.0, x2(z)], k, force(beyond))
    assert not mech.yielding and mech.stop_m == pytest.approx(0.0165, rel=1e-12)
    # to z -0.0095: 0.005 of the 0.0245 increment past -0.0045
    np.testing.assert_allclose(m.stiffness([0.0, x2(-0.0245)]),
                               K0 - (0.005 / 0.0245) * LAM * np.outer(U, U), rtol=1e-9)
    m = YieldMechanisms(K0)
    for z, k, beyond in samples:
        m.observe([0.0, x2(z)], k, force(beyond))
    (mech,) = m.mechanisms
    assert mech.first_onset_m == pytest.approx(0.010) and mech.stop_m == pytest.approx(0.016)


def test_only_the_pushovers_mechanisms_use_the_deficit_force():
    """The builder asks the part for its deficit force only when a mechanism the pushover
    found is there (no other mechanism uses it)."""
    assert not YieldMechanisms(K0).uses_deficit
    assert not YieldMechanisms(K0, [VirginMechanism(U, LAM, -0.01, 0.01, False)]).uses_deficit
    assert YieldMechanisms(K0, [VirginMechanism(U, LAM, -0.01, 0.01, True)]).uses_deficit


def test_two_adjacent_stories_keep_their_own_deficits():
    """Stories 2 and 3 of a three-floor frame, both found by the pushover, share floor 2: their
    directions are not orthogonal (``u2 . u3 = -1/2``). Story 2 yields past z2 0.004 and goes
    on; story 3 yields past z3 0.003 within the step to 0.0034, then unloads while story 2
    goes on. Each keeps its own direction and deficit (the tangent's eigenvectors mix them),
    story 3's onset is placed at 0.003 from its own share of the deficit force (its
    projection, ``lambda3 (z3 - 0.003) - lambda2 (z2 - 0.004) / 2``, holds story 2's), and
    its end at 0.0034."""
    k = np.array([K, 0.9 * K, 0.7 * K])
    k0 = np.array([[k[0] + k[1], -k[1], 0.0], [-k[1], k[1] + k[2], -k[2]], [0.0, -k[2], k[2]]])
    u2 = np.array([-1.0, 1.0, 0.0]) / np.sqrt(2.0)
    u3 = np.array([0.0, -1.0, 1.0]) / np.sqrt(2.0)
    lam2, lam3 = (1 - B) * 2 * k[1], (1 - 0.05) * 2 * k[2]
    m = YieldMechanisms(k0, [VirginMechanism(u2, lam2, -0.004, 0.004, True),
                             VirginMechanism(u3, lam3, -0.003, 0.003, True)])
    story2, story3 = m.mechanisms

    def x(z2, z3):                                  # floor 1 held at 0
        x2 = z2 * np.sqrt(2.0)
        return [0.0, x2, x2 + z3 * np.sqrt(2.0)]

    def sample(z2, z3, yielding2, yielding3, beyond3):
        tangent = k0 - yielding2 * lam2 * np.outer(u2, u2) - yielding3 * lam3 * np.outer(u3, u3)
        force = lam2 * max(z2 - 0.004, 0.0) * u2 + lam3 * beyond3 * u3
        m.observe(x(z2, z3), None if not (yielding2 or yielding3) else tangent, force)

    sample(0.0, 0.0, False, False, 0.0)
    sample(0.003, 0.001, False, False, 0.0)
    sample(0.005, 0.002, True, False, 0.0)
    sample(0.007, 0.0034, True, True, 0.0004)
    assert story2.yielding and story3.yielding and len(m.mechanisms) == 2
    assert story2.deficit_N_per_m == pytest.approx(lam2, rel=1e-9)
    assert story3.deficit_N_per_m == pytest.approx(lam3, rel=1e-9)
    assert story3.onset_m == pytest.approx(0.003, rel=1e-9)
    # story 2 goes on, story 3 unloads: story 3's deficit given back, story 2's kept
    increment = np.subtract(x(0.009, 0.0030), x(0.007, 0.0034))
    np.testing.assert_allclose(m.stiffness(increment), k0 - lam2 * np.outer(u2, u2),
                               rtol=1e-9, atol=1e-6 * K)
    sample(0.009, 0.0030, True, False, 0.0004)
    assert story2.yielding and not story3.yielding
    assert story3.stop_m == pytest.approx(0.0034, rel=1e-9)


def test_a_gradually_yielding_member_softens_on_over_the_prediction():
    """A member whose deficit grows as it yields (``lambda = S (z - 0.008)``: a ``Steel02``
    story, linearized) takes over a predicted increment ``dz`` its mean deficit, ``lambda +
    S dz / 2``, losing at most half of what it has left along ``U`` with floor 2 free (story
    2's own ``2 K - lambda``); it unloads elastically; a held tangent keeps the slope; a
    mechanism whose direction turns between samples (several members) is held at its
    tangent."""
    slope = 2e7                                              # S [N/m^2]
    x2 = lambda z: z * np.sqrt(2.0)                          # noqa: E731 (x1 held at 0)

    def tangent(z, u=U):
        return K0 - slope * (z - 0.008) * np.outer(u, u)

    m = YieldMechanisms(K0, free_dofs=[1])
    m.observe([0.0, 0.0], None)
    for z in (0.010, 0.012, 0.014):
        m.observe([0.0, x2(z)], tangent(z))
    (mech,) = m.mechanisms
    assert mech.slope_N_per_m2 == pytest.approx(slope, rel=1e-9)
    np.testing.assert_allclose(m.stiffness([0.0, x2(0.004)]),
                               tangent(0.014) - 0.5 * slope * 0.004 * np.outer(U, U),
                               rtol=1e-9)
    left = 2 * K - slope * (0.014 - 0.008)                   # story 2's, along U
    np.testing.assert_allclose(m.stiffness([0.0, x2(0.1)]),
                               tangent(0.014) - 0.5 * left * np.outer(U, U), rtol=1e-9)
    np.testing.assert_allclose(m.stiffness([0.0, x2(-0.004)]), K0, rtol=1e-12)
    m.observe([0.0, x2(0.015)], tangent(0.014))              # held: the slope stays
    assert mech.slope_N_per_m2 == pytest.approx(slope, rel=1e-9)

    turning = YieldMechanisms(K0)
    turning.observe([0.0, 0.0], None)
    for i, z in enumerate((0.010, 0.012, 0.014)):
        angle = np.pi / 4 + 1e-3 * i                         # the direction turns
        u = np.array([-np.cos(angle), np.sin(angle)])
        turning.observe([0.0, x2(z)], tangent(z, u))
    (mech,) = turning.mechanisms
    assert mech.slope_N_per_m2 == 0.0
    assert turning.stiffness([0.0, x2(0.004)]) is None       # its tangent held


def test_two_adjacent_gradual_members_each_follow_their_own_slope():
    """Stories 2 and 3 of a three-floor frame yielding gradually together (``lambda_j =
    S_j (z_j - 0.002)``), both found by the pushover: their deficits split over their
    directions (the eigenvectors mix them and turn as the two grow at their own rates), each
    its own slope. A deficit their directions do not give (a third member, along floor 1
    alone) leaves the gradual ones out of the split: an eigen-direction as before."""
    k = np.array([K, 0.9 * K, 0.7 * K])
    k0 = np.array([[k[0] + k[1], -k[1], 0.0], [-k[1], k[1] + k[2], -k[2]], [0.0, -k[2], k[2]]])
    u2 = np.array([-1.0, 1.0, 0.0]) / np.sqrt(2.0)
    u3 = np.array([0.0, -1.0, 1.0]) / np.sqrt(2.0)
    s2, s3 = 3e7, 1e7

    def x(z2, z3):
        x2 = z2 * np.sqrt(2.0)
        return [0.0, x2, x2 + z3 * np.sqrt(2.0)]

    def tangent(z2, z3):
        return (k0 - s2 * max(z2 - 0.002, 0.0) * np.outer(u2, u2)
                - s3 * max(z3 - 0.002, 0.0) * np.outer(u3, u3))

    m = YieldMechanisms(k0, [VirginMechanism(u2, 1.0, -0.002, 0.002, False),
                             VirginMechanism(u3, 1.0, -0.002, 0.002, False)], free_dofs=[1, 2])
    story2, story3 = m.mechanisms
    m.observe(x(0.0, 0.0), None)
    for z2, z3 in ((0.003, 0.0025), (0.004, 0.003), (0.005, 0.0035)):
        m.observe(x(z2, z3), tangent(z2, z3))
    assert len(m.mechanisms) == 2 and story2.yielding and story3.yielding
    assert story2.slope_N_per_m2 == pytest.approx(s2, rel=1e-6)
    assert story3.slope_N_per_m2 == pytest.approx(s3, rel=1e-6)
    increment = np.subtract(x(0.006, 0.004), x(0.005, 0.0035))
    expected = (tangent(0.005, 0.0035) - 0.5 * s2 * 0.001 * np.outer(u2, u2)
                - 0.5 * s3 * 0.0005 * np.outer(u3, u3))
    np.testing.assert_allclose(m.stiffness(increment), expected, rtol=1e-6, atol=1e-6 * K)

    other = YieldMechanisms(k0, [VirginMechanism(u2, 1.0, -0.002, 0.002, False)])
    other.observe(x(0.0, 0.0), None)
    e1 = np.array([1.0, 0.0, 0.0])
    other.observe(x(0.001, 0.0), k0 - 1e5 * np.outer(e1, e1))
    (gradual, found) = other.mechanisms
    assert not gradual.yielding and found.yielding
    np.testing.assert_allclose(abs(found.direction), e1, atol=1e-9)
