"""Particle sets: zero-copy numpy views, resizing guarded while views live,
steppers in place."""
import numpy as np
import pytest

import otfp


def make_set(n=30, seed=2):
    rng = np.random.default_rng(seed)
    return otfp.ParticleSet(3, rng.uniform(-0.4, 0.4, (n, 3)), np.full(n, 0.15), np.full(n, 1.0 / n))


def test_views_share_the_storage():
    ps = make_set()
    m = ps.masses
    m[:] = 2.0  # written through the view: the C++ side sees it
    assert ps.total_mass() == pytest.approx(60.0, rel=1e-15)
    x = ps.positions
    assert x.shape == (30, 3) and x.base is not None
    assert not ps.ids.flags.writeable
    assert list(ps.ids) == list(range(30))


def test_resizing_with_live_views_is_refused():
    ps = make_set()
    x = ps.positions
    with pytest.raises(BufferError):
        ps.add([0, 0, 0], 0.1, 1.0)
    with pytest.raises(BufferError):
        ps.remove(0)
    del x
    ps.add([0, 0, 0], 0.1, 1.0)
    assert len(ps) == 31


def test_step_in_place_keeps_views_valid_and_ids_attached():
    ps = make_set()
    x = ps.positions
    ids0 = np.array(ps.ids)
    x0 = {int(i): x[k].copy() for k, i in enumerate(ids0)}
    stepper = otfp.ImplicitStepper(None, otfp.ImplicitOptions(), dim=3)
    summary = stepper.step(ps, 1e-3)
    assert summary.accepted and summary.evaluations > 0
    # The same view shows the new state; displacements are small and follow the ids.
    moved = max(np.linalg.norm(x[k] - x0[int(i)]) for k, i in enumerate(ps.ids))
    assert 0.0 < moved < 0.1
    assert sorted(ps.ids) == sorted(ids0)


def test_explicit_step_matches_euler_on_the_force():
    # One explicit Euler step of (27) from a symmetric pair moves both blobs
    # apart by the same amount (momentum-free spreading).
    ps = otfp.ParticleSet(1, np.array([[-0.05], [0.05]]), np.array([0.1, 0.1]), np.array([0.5, 0.5]))
    stepper = otfp.ExplicitStepper(None, otfp.ExplicitOptions(sort_particles=False), dim=1)
    summary = stepper.step(ps, 1e-4)
    assert summary.accepted
    x = ps.positions[:, 0]
    assert x[0] < -0.05 and x[1] > 0.05
    assert x[0] == pytest.approx(-x[1], rel=1e-14)


def test_dimension_mismatch_and_bad_values():
    with pytest.raises(ValueError, match="dim"):
        otfp.ImplicitStepper(otfp.make_ball(3, [0, 0, 0], 1.0), dim=2)
    with pytest.raises(ValueError, match="widths"):
        otfp.ParticleSet(3, np.zeros((2, 3)), np.ones(3), np.ones(2))
    ps = make_set()
    with pytest.raises(ValueError, match="mass"):
        ps.add([0, 0, 0], 0.1, -1.0)


def test_csv_round_trip(tmp_path):
    ps = make_set()
    path = tmp_path / "p.csv"
    path.write_text(otfp.particles_csv(ps))
    back = otfp.read_particles(path, 3)
    np.testing.assert_array_equal(back.positions, ps.positions)
    np.testing.assert_array_equal(back.widths, ps.widths)
    np.testing.assert_array_equal(back.ids, ps.ids)


def test_staggered_lattice_fill_is_body_centred_in_3d():
    counts = [2, 2, 2]
    n = otfp.lattice_point_count(3, counts, staggered=True)
    assert n == 16 and otfp.lattice_point_count(3, counts) == 8
    box = otfp.make_periodic_box(3, [0, 0, 0], [1, 1, 1])
    ps = otfp.fill_particles(box, otfp.FillOptions(count=n, width_s=0.1, mass=1.0 / n, lattice=True,
                                                   staggered=True, lattice_counts=counts, hi=[1, 1, 1]))
    x = np.sort(np.unique(np.round(ps.positions[:, 0], 12)))
    assert list(x) == [0.125, 0.375, 0.625, 0.875]  # cells of 1/2, points at 1/4 and 3/4 of each
    with pytest.raises(ValueError, match=r"fill lattice count along y = 3"):
        otfp.fill_particles(otfp.make_periodic_box(2, [0, 0, 0], [1, 1, 0]),
                            otfp.FillOptions(count=6, width_s=0.1, mass=0.1, lattice=True, staggered=True,
                                             lattice_counts=[2, 3, 1], hi=[1, 1, 0]))
