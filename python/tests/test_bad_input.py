"""Bad input from Python gets a one-line ValueError (or TypeError for a
wrong kind of object) naming the field, the value and the rule, instead of
a later failure elsewhere, a pybind11 message or a silent change."""
import numpy as np
import pytest

import otfp


def one_line(excinfo):
    text = str(excinfo.value)
    assert "\n" not in text, text
    return text


def particles(n=20, dim=3, seed=1):
    rng = np.random.default_rng(seed)
    return otfp.ParticleSet(dim, rng.uniform(-0.5, 0.5, (n, dim)), np.full(n, 0.2), np.full(n, 1.0 / n))


def box():
    return otfp.make_box(3, [-1, -1, -1], [1, 1, 1])


# ---- non-finite positions (written through a view) are bad input, not a diverged step

def test_a_nan_position_is_refused_by_the_steppers_naming_the_row():
    ps = particles()
    ps.positions[3, 1] = np.nan
    before = np.array(ps.widths)
    stepper = otfp.ImplicitStepper(box(), otfp.ImplicitOptions(kappa=1.0), barrier_stiffness=100.0)
    with pytest.raises(ValueError) as e:
        stepper.step(ps, 1e-3)
    text = one_line(e)
    assert "particles.positions" in text and "row 3" in text and "id 3" in text and "nan" in text
    assert "diverged" not in text
    with pytest.raises(ValueError, match=r"particles\.positions: row 3"):
        otfp.ExplicitStepper(options=otfp.ExplicitOptions(kappa=1.0), dim=3).step(ps, 1e-4)
    assert np.array_equal(ps.widths, before)


def test_a_simulation_refuses_non_finite_particles_at_start():
    domain = otfp.make_ball(3, [0, 0, 0], 1.0)
    sim = otfp.Simulation(domain, [otfp.BoundaryData(patch=0, kind="dirichlet", value=1.0)],
                          otfp.SimulationOptions(particle_mass=0.05, width_s=0.2, barrier_stiffness=100.0,
                                                 projection=dict(layer_b=0.15)))
    ps = particles()
    ps.positions[7] = [0.0, np.inf, 0.0]
    with pytest.raises(ValueError, match=r"particles\.positions: row 7 \(id 7\) = \(0, inf, 0\): must be finite"):
        sim.start(ps)
    assert not sim.started
    ps = particles()
    ps.widths[2] = 0.0
    with pytest.raises(ValueError, match=r"particles\.widths: row 2 \(id 2\) = 0: must be finite and > 0"):
        sim.start(ps)
    ps = particles()
    ps.birth_times[4] = np.nan
    with pytest.raises(ValueError, match=r"particles\.birth_times: row 4 \(id 4\) = nan: must be finite"):
        sim.start(ps)


def test_non_finite_arrays_are_refused_where_they_come_in():
    x = np.zeros((4, 3))
    x[2, 0] = np.nan
    with pytest.raises(ValueError, match=r"positions: row 2 = \(nan, 0, 0\): must be finite"):
        otfp.ParticleSet(3, x, np.full(4, 0.2), np.full(4, 0.25))
    f = otfp.Functional(options=otfp.FunctionalOptions(dt=0.01), dim=3)
    with pytest.raises(ValueError, match=r"x_ref: row 2 = \(nan, 0, 0\): must be finite"):
        f.set_reference(x, np.full(4, 0.2), np.full(4, 0.25))
    with pytest.raises(ValueError, match="points: row 2"):
        box().signed_distance(x)


# ---- the Functional's widths and masses

def test_functional_refuses_zero_widths_and_negative_masses():
    rng = np.random.default_rng(2)
    x = rng.uniform(-1, 1, (10, 3))
    f = otfp.Functional(options=otfp.FunctionalOptions(dt=0.01), dim=3)
    with pytest.raises(ValueError) as e:
        f.set_reference(x, np.zeros(10), np.full(10, 0.1))
    assert one_line(e) == "s_ref: row 0 = 0: must be finite and > 0"
    with pytest.raises(ValueError, match=r"masses: row 3 = -0.1: must be finite and > 0"):
        m = np.full(10, 0.1)
        m[3] = -0.1
        f.set_reference(x, np.full(10, 0.3), m)
    f.set_reference(x, np.full(10, 0.3), np.full(10, 0.1))
    s = np.full(10, 0.3)
    s[9] = -0.3
    with pytest.raises(ValueError, match=r"^s: row 9 = -0.3: must be finite and > 0$"):
        f.evaluate(x, s)


# ---- shapes: a 2-D set, add()

def test_a_2d_set_refuses_a_nonzero_third_coordinate():
    x = np.random.default_rng(3).uniform(-1, 1, (5, 3))
    with pytest.raises(ValueError) as e:
        otfp.ParticleSet(2, x, np.full(5, 0.2), np.full(5, 0.2))
    text = one_line(e)
    assert "positions" in text and "shape (5, 3)" in text and "dim = 2" in text
    # A zero third column (the (n, 3) positions of a 2-D set) is what it means: accepted.
    ps = otfp.ParticleSet(2, np.c_[x[:, :2], np.zeros(5)], np.full(5, 0.2), np.full(5, 0.2))
    assert np.array_equal(ps.positions[:, :2], x[:, :2])
    q = otfp.ParticleSet(2, ps.positions, ps.widths, ps.masses)  # round trip of its own views
    assert np.array_equal(q.positions, ps.positions)
    with pytest.raises(ValueError, match=r"x: 3 coordinates for a dim = 2 set: coordinate 2 must be 0"):
        otfp.ParticleSet(2).add([0.1, 0.2, 0.3], 0.1, 1.0)


def test_add_takes_one_point_and_a_finite_birth_time():
    ps = otfp.ParticleSet(3)
    with pytest.raises(ValueError) as e:
        ps.add(np.zeros((3, 3)), 0.1, 1.0)
    assert "shape (3, 3)" in one_line(e) and "one point" in str(e.value)
    assert len(ps) == 0
    with pytest.raises(ValueError, match=r"^birth_time = nan: must be finite$"):
        ps.add([0, 0, 0], 0.1, 1.0, float("nan"))
    assert len(ps) == 0
    assert ps.add([0, 0, 0], 0.1, 1.0, -0.5) == 0
    assert ps.birth_times[0] == -0.5


# ---- numbers: complex values, seeds

def test_complex_arrays_are_refused():
    x = np.zeros((4, 3)) + 0j
    with pytest.raises(ValueError) as e:
        otfp.ParticleSet(3, x, np.full(4, 0.2), np.full(4, 0.25))
    assert one_line(e) == "positions: complex values (dtype complex128): must be real"
    with pytest.raises(ValueError, match=r"^widths: complex values"):
        otfp.ParticleSet(3, np.zeros((4, 3)), np.full(4, 0.2) + 1j, np.full(4, 0.25))
    with pytest.raises(ValueError, match=r"^points: dtype <U1: must be real numbers$"):
        box().contains(np.array(["a", "b", "c"]))


@pytest.mark.parametrize("value", [2**70, -1])
def test_a_seed_out_of_range_says_the_range(value):
    with pytest.raises(ValueError) as e:
        otfp.SimulationOptions(seed=value)
    text = one_line(e)
    assert "SimulationOptions.seed" in text and "0 .. 2**64 - 1" in text and "expected int, got int" not in text
    with pytest.raises(ValueError, match=r"^seed = .*: must be an integer in 0 \.\. 2\*\*64 - 1$"):
        otfp.Rng(value)
    with pytest.raises(ValueError, match=r"^seed = .*: must be an integer in 0 \.\. 2\*\*64 - 1$"):
        otfp.fill_particles(box(), otfp.FillOptions(count=4, width_s=0.1, mass=0.1), seed=value)
    o = otfp.SimulationOptions()
    o.seed = 2**64 - 1  # the top of the range
    assert o.seed == 2**64 - 1
    assert otfp.Rng(2**64 - 1).uniform() == otfp.Rng(2**64 - 1).uniform()


def test_an_int_field_out_of_range_says_the_range():
    with pytest.raises(ValueError, match=r"MinimizerOptions.max_iterations = 4294967296: must be an integer in "
                                         r"-2\*\*31 \.\. 2\*\*31 - 1"):
        otfp.MinimizerOptions(max_iterations=2**32)


# ---- the observer's return value

@pytest.mark.parametrize("value", [np.array([1, 2]), "stop", 1])
def test_an_observer_returning_something_else_than_none_or_a_bool_is_told_what_to_return(value):
    domain = otfp.make_ball(3, [0, 0, 0], 1.0)
    sim = otfp.Simulation(domain, [otfp.BoundaryData(patch=0, kind="dirichlet", value=1.0)],
                          otfp.SimulationOptions(particle_mass=0.05, width_s=0.2, barrier_stiffness=100.0,
                                                 projection=dict(layer_b=0.15)))
    sim.start(otfp.ParticleSet(3))
    with pytest.raises(TypeError) as e:
        sim.run_until(0.003, 0.001, lambda s, step: value)
    text = one_line(e)
    assert "observer returned" in text and type(value).__name__ in text
    assert "None" in text and "True" in text and "False" in text
    assert sim.step_count == 1  # stopped after the step whose observer failed
    # numpy's bool is a bool.
    assert not sim.run_until(0.003, 0.001, lambda s, step: np.bool_(False))
    assert sim.step_count == 2


def test_special_files_are_refused_at_once(tmp_path):
    """read_particles and load_checkpoint on /dev/zero or a FIFO raise a
    ValueError naming the file, without reading (they used to read until
    MemoryError, or hang on a FIFO with no writer)."""
    import os
    import otfp
    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)
    link = tmp_path / "zero.vtp"
    os.symlink("/dev/zero", link)
    for path in (str(link), str(fifo)):
        with pytest.raises(ValueError, match="regular file"):
            otfp.read_particles(path, 3)
    ball = otfp.make_ball(3, [0, 0, 0], 1.0)
    data = [otfp.BoundaryData(patch=0, kind="dirichlet", value=0.2)]
    opts = otfp.converging_options(ball, data, n_inf=100, length_L=1.0, particle_mass=0.01)
    sim = otfp.Simulation(ball, data, opts)
    for path in ("/dev/zero", str(fifo), str(link)):
        with pytest.raises(ValueError, match="regular file"):
            sim.load_checkpoint(path)
