"""The bound functional (28): its gradient against numpy central differences."""
import numpy as np
import pytest

import otfp


def cloud(n=40, dim=3, seed=3):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-0.6, 0.6, (n, dim))
    s = rng.uniform(0.15, 0.3, n)
    m = rng.uniform(0.5, 1.5, n) / n
    return x, s, m


@pytest.mark.parametrize("optimise_widths", [False, True])
def test_gradient_matches_central_differences(optimise_widths):
    x_ref, s_ref, m = cloud()
    domain = otfp.make_ball(3, [0, 0, 0], 0.55)  # some particles outside: the barrier is active
    f = otfp.Functional(domain, otfp.FunctionalOptions(dt=0.01, kappa=0.7, optimise_widths=optimise_widths),
                        barrier_stiffness=50.0)
    f.set_reference(x_ref, s_ref, m)
    rng = np.random.default_rng(7)
    x = x_ref + 0.02 * rng.standard_normal(x_ref.shape)
    s = s_ref * (1.0 + 0.05 * rng.standard_normal(s_ref.shape))
    r = f.evaluate(x, s, all_pairs=True)  # the O(n^2) sum: no cut-off in the comparison
    assert r["barrier"] > 0.0
    assert r["value"] == pytest.approx(r["transport"] + r["entropy"] + r["barrier"], rel=1e-14)
    h = 1e-6
    for p in range(0, 40, 7):
        for k in range(3):
            xp, xm = x.copy(), x.copy()
            xp[p, k] += h
            xm[p, k] -= h
            fd = (f.evaluate(xp, s, True)["value"] - f.evaluate(xm, s, True)["value"]) / (2 * h)
            assert r["gradient_x"][p, k] == pytest.approx(fd, rel=1e-6, abs=1e-7), (p, k)
        if optimise_widths:
            sp, sm = s.copy(), s.copy()
            sp[p] += h
            sm[p] -= h
            fd = (f.evaluate(x, sp, True)["value"] - f.evaluate(x, sm, True)["value"]) / (2 * h)
            assert r["gradient_s"][p] == pytest.approx(fd, rel=1e-6, abs=1e-7), p
        else:
            assert r["gradient_s"] is None


def test_cell_list_agrees_with_all_pairs():
    x, s, m = cloud(n=200, seed=5)
    f = otfp.Functional(None, otfp.FunctionalOptions(dt=0.01), dim=3)
    f.set_reference(x, s, m)
    a = f.evaluate(x, s)
    b = f.evaluate(x, s, all_pairs=True)
    assert a["value"] == pytest.approx(b["value"], rel=1e-7)
    np.testing.assert_allclose(a["gradient_x"], b["gradient_x"], rtol=1e-6, atol=1e-8)


def test_density_of_one_blob_is_its_gaussian_peak():
    # rho(x_p) of a lone blob: m (beta/pi)^(d/2), beta = 1/s^2.
    f = otfp.Functional(None, otfp.FunctionalOptions(dt=1.0), dim=3)
    x, s, m = np.zeros((1, 3)), np.array([0.5]), np.array([2.0])
    f.set_reference(x, s, m)
    r = f.evaluate(x, s)
    assert r["density"][0] == pytest.approx(2.0 * (4.0 / np.pi) ** 1.5, rel=1e-14)
    assert r["transport"] == 0.0


def test_bad_arrays_raise_value_error():
    f = otfp.Functional(None, otfp.FunctionalOptions(dt=1.0), dim=3)
    with pytest.raises(ValueError, match="set_reference"):
        f.evaluate(np.zeros((2, 3)), np.ones(2))
    with pytest.raises(ValueError, match="s_ref"):
        f.set_reference(np.zeros((2, 3)), np.ones(3), np.ones(2))
    with pytest.raises(ValueError, match="dt"):
        otfp.FunctionalOptions(dt=-1.0)
