"""otfp.Simulation from Python: the same steps as the C++ command-line tool
bit for bit, the observer, checkpoints and bad input."""
import math
import subprocess

import numpy as np
import pytest

import otfp

OVERRIDES = ["particles.n_inf=150", "run.t_end=0.5", "run.dt_factor=1"]


def rows_without_region(csv_text):
    """particles_final.csv rows without the region column (particles_csv() writes 0 there)."""
    lines = csv_text.strip().splitlines()
    assert lines[0].split(",")[-1] == "region"
    return [line.rsplit(",", 1)[0] for line in lines]


TAO = pytest.mark.skipif(not otfp.backend_available(otfp.Backend.Tao),
                         reason="built without OTFP_WITH_MPI (no TAO backend)")


@pytest.mark.parametrize("extra", [[], ["solver.stepper=explicit", "run.dt_factor=0.25"],
                                   ["solver.time_scheme=bdf2", "solver.backend=nlopt"],
                                   pytest.param(["solver.backend=tao"], marks=TAO)])
def test_steps_equal_the_command_line_tool_bit_for_bit(tmp_path, source_dir, otfp_cli, extra):
    config = str(source_dir / "examples" / "sphere_dirichlet.toml")
    overrides = OVERRIDES + extra + ["run.max_steps=3"]
    cmd = [otfp_cli, "run", config, "--out", str(tmp_path / "cli")]
    for o in overrides:
        cmd += ["--set", o]
    subprocess.run(cmd, check=True, capture_output=True)

    run = otfp.load_config(config, overrides)
    assert run.n_steps > 3  # max_steps stops the tool after step 3
    sim = run.make_simulation()
    for k in range(1, 4):  # the tool's fixed grid: t_k = k dt, the last step ends on t_end
        sim.advance_to(run.t_end if k == run.n_steps else k * run.dt)
    assert sim.step_count == 3
    ours = rows_without_region(otfp.particles_csv(sim.particles))
    theirs = rows_without_region((tmp_path / "cli" / "particles_final.csv").read_text())
    assert len(ours) > 100
    assert ours == theirs  # shortest round-trip decimal forms: equal strings are equal doubles


def small_simulation():
    domain = otfp.make_ball(3, [0, 0, 0], 1.0)
    n = 120
    opts = otfp.SimulationOptions(particle_mass=1.0 / n, width_s=0.12, barrier_stiffness=400.0,
                                  projection=dict(layer_b=0.15), seed=11)
    sim = otfp.Simulation(domain, [otfp.BoundaryData(patch=0, kind="dirichlet", value=1.0)], opts)
    fill = otfp.fill_particles(domain, otfp.FillOptions(count=n // 4, width_s=0.12, mass=1.0 / n), seed=5)
    sim.start(fill)
    return sim


def test_run_is_the_library_time_loop_and_resumes_on_its_grid(tmp_path):
    """Simulation.run: the grid t_k = k dt, checkpoints at the cadence and at the end, a stop by the
    observer, and a run continued from a checkpoint in another Simulation equal to one in one go."""
    control = otfp.RunControl(t_end=0.01, dt=0.0025, checkpoint_interval=2)
    whole = small_simulation()
    seen, saved = [], []
    assert whole.run(control, lambda s, step: seen.append((step.step, step.t_end)),
                     lambda s: saved.append(s.step_count)) == otfp.RunEnd.Completed
    assert seen == [(1, 0.0025), (2, 0.005), (3, 3 * 0.0025), (4, 0.01)]
    assert saved == [2, 4]
    assert whole.time_grid.k_end == 4 and whole.finished(control)

    head = small_simulation()
    assert str(head.run(control, lambda s, step: step.step < 3)) == "stopped"
    path = str(tmp_path / "run.bin")
    head.save_checkpoint(path)
    tail = small_simulation()
    tail.load_checkpoint(path)
    assert tail.time_grid.dt == 0.0025
    assert tail.run(control) == otfp.RunEnd.Completed
    assert tail.time == 0.01
    assert np.array_equal(tail.particles.positions, whole.particles.positions)
    with pytest.raises(ValueError, match="dt = 0: must be finite and > 0"):
        tail.run(otfp.RunControl(t_end=1.0, dt=0.0))


def test_observer_sees_every_step_and_can_stop():
    sim = small_simulation()
    seen = []
    assert sim.run_until(0.01, 0.0025, lambda s, step: seen.append((step.step, step.t_end, s.time)))
    assert [k for k, _, _ in seen] == [1, 2, 3, 4]
    assert all(t == ts for _, t, ts in seen)  # the observer runs after the step
    assert seen[-1][1] == 0.01

    def stop_after_two(s, step):
        return step.step < 6

    assert not sim.run_until(0.03, 0.0025, stop_after_two)
    assert sim.step_count == 6
    led = sim.ledger
    assert len(sim.particles) == led.expected_particles()


def test_observer_exception_propagates():
    sim = small_simulation()

    def boom(s, step):
        raise KeyError("from the observer")

    with pytest.raises(KeyError, match="from the observer"):
        sim.run_until(0.01, 0.0025, boom)
    assert sim.step_count == 1


def test_checkpoint_round_trip(tmp_path):
    a = small_simulation()
    a.run_until(0.005, 0.0025)
    path = tmp_path / "state.bin"
    a.save_checkpoint(path, "mine")
    a.run_until(0.01, 0.0025)
    b = small_simulation()
    b.run_until(0.0025, 0.0025)  # a different state, overwritten by the checkpoint
    assert b.load_checkpoint(path) == "mine"
    assert b.time == 0.005 and b.step_count == 2
    b.run_until(0.01, 0.0025)
    assert otfp.particles_csv(a.particles) == otfp.particles_csv(b.particles)
    path.write_bytes(path.read_bytes()[:-3])  # damaged: refused, state kept
    with pytest.raises(ValueError):
        b.load_checkpoint(path)
    assert b.step_count == 4


def test_bad_options_raise_value_error_naming_the_field(source_dir):
    with pytest.raises(ValueError, match="particle_mass"):
        otfp.SimulationOptions(particle_mass=-1.0, width_s=0.1, barrier_stiffness=1.0)
    with pytest.raises(ValueError, match="time_scheme"):
        otfp.ImplicitOptions(time_scheme="bdf3")
    with pytest.raises(ValueError, match="no field 'kapa'"):
        otfp.ImplicitOptions(kapa=1.0)
    with pytest.raises(ValueError, match="max_iterations"):
        otfp.ImplicitOptions(minimizer=dict(max_iterations=0))
    with pytest.raises(ValueError, match="kappa"):
        otfp.ExplicitOptions(kappa=float("nan"))
    domain = otfp.make_ball(3, [0, 0, 0], 1.0)
    opts = otfp.SimulationOptions(particle_mass=0.01, width_s=0.1, barrier_stiffness=100.0)
    with pytest.raises(ValueError, match="patch"):
        otfp.Simulation(domain, [otfp.BoundaryData(patch=3, kind="dirichlet", value=1.0)], opts)
    with pytest.raises(otfp.ConfigError, match="particles.n_inf"):
        otfp.load_config(source_dir / "examples" / "sphere_dirichlet.toml", ["particles.n_inf=-5"])


def test_step_failure_is_a_runtime_error_and_keeps_the_state():
    sim = small_simulation()
    sim.run_until(0.0025, 0.0025)
    before = otfp.particles_csv(sim.particles)
    with pytest.raises(ValueError):
        sim.advance_to(0.001)  # before the current time
    assert otfp.particles_csv(sim.particles) == before
    assert issubclass(otfp.StepFailure, RuntimeError)


def test_measure_and_references():
    sim = small_simulation()
    sim.run_until(0.01, 0.0025)
    ms, region = sim.measure([0, 0, 0])
    assert ms.n_particles == len(sim.particles) == len(region)
    assert ms.n_inside == int(np.sum(region == 0))
    ps = sim.particles
    assert ms.mass_total == pytest.approx(ps.total_mass(), rel=1e-14)
    inside = region == 0
    j = np.sum(ps.masses[inside] * np.sum(ps.positions[inside] ** 2, axis=1))
    assert ms.polar_inertia == pytest.approx(j, rel=1e-12)
    # Crank's uptake, vectorised, equals the scalar calls.
    tau = np.array([0.01, 0.1, 1.0])
    assert list(otfp.analytic.crank_sphere_uptake(tau)) == [otfp.analytic.crank_sphere_uptake(t) for t in tau]


def test_reference_objects():
    # Crank's sphere on the simulation's measures: the columns are the analytic curves.
    sim = small_simulation()
    assert otfp.reference_names() == ["crank_sphere", "crank_slab", "free_space", "cosine_mode"]
    ref = otfp.make_reference("crank_sphere", otfp.ReferenceSetup(radius=1.0, M_inf=4.18879020478639 * 1.0))
    assert ref.columns == ["reference_mass_ratio", "error_mass_ratio"] and ref.has_mass_blob_error
    rows = []
    for k in range(3):
        if k:
            sim.advance(0.0025)
        ms, _ = sim.measure([0, 0, 0])
        row = ref.row(sim.time, ms, mass_blob=sim.blob_mass())
        m = otfp.analytic.crank_sphere_uptake(sim.time)
        assert row.values == [m, ms.mass_inside / 4.18879020478639 - m]
        assert row.error_mass_blob == sim.blob_mass() / 4.18879020478639 - m
        rows.append(row.values)
    stats = ref.statistics()
    assert [s.measured for s in stats] == ["mass_ratio"]
    assert stats[0].max_abs_error == max(abs(r[1]) for r in rows)
    # The state continues the statistics exactly.
    again = otfp.make_reference("crank_sphere", otfp.ReferenceSetup(radius=1.0, M_inf=4.18879020478639))
    again.load_state(ref.save_state())
    assert again.statistics()[0].state() == stats[0].state()
    # The decay-rate fit and the cosine mode's summary entries.
    t = np.linspace(0.0, 0.5, 11)
    assert otfp.decay_rate_fit(t, 0.3 * np.exp(-2.5 * t)) == pytest.approx(2.5, rel=1e-12)
    cos = otfp.make_reference("cosine_mode", otfp.ReferenceSetup(dim=2, wavenumber=2 * np.pi, constant_dt=0.01))
    ps = otfp.ParticleSet(2)
    ps.add([0.0, 0.0], 0.05, 1.0)
    cos.row(0.0, particles=ps)
    assert cos.summary()["kappa_k2"] == pytest.approx(4 * np.pi ** 2)
    assert cos.summary()["rows_fitted"] == 1
    with pytest.raises(ValueError):
        otfp.make_reference("crank_cylinder", otfp.ReferenceSetup())


def test_brief_report_prints_six_significant_digits():
    sim = small_simulation()
    sim.advance(0.1)
    step = sim.advance(0.2)
    assert step.t_end == 0.1 + 0.2 != 0.3  # 0.30000000000000004
    report = step.brief_report()
    assert report.startswith("step 2: t = 0.3 (dt = 0.2), F = "), report
    f_text = report.split("F = ")[1].split(",")[0]
    assert float(f_text) == pytest.approx(step.diffusion.f_after, rel=1e-5)
    assert len(f_text.lstrip("-").replace(".", "").split("e")[0].lstrip("0")) <= 6


def test_quiet_reservoir_is_the_default_and_exact_is_one_field_away():
    import otfp
    ball = otfp.make_ball(3, [0, 0, 0], 1.0)
    g = 3.0 / (4.0 * 3.141592653589793)
    data = [otfp.BoundaryData(patch=0, kind="dirichlet", value=g)]
    opts = otfp.converging_options(ball, data, n_inf=100, length_L=1.0, particle_mass=0.01)
    assert str(opts.projection.reservoir_control) == "quiet"
    quiet = otfp.Simulation(ball, data, opts)
    quiet.start(otfp.ParticleSet(3), 0.0)
    # The quiet control draws no random numbers: two seeds give the same run.
    seed = opts.seed
    opts.seed = seed + 1
    twin = otfp.Simulation(ball, data, opts)
    opts.seed = seed
    twin.start(otfp.ParticleSet(3), 0.0)
    assert (quiet.particles.positions == twin.particles.positions).all()
    # M_rho of the band alone is its tails inside Omega: a half-space at 2 g
    # spills 2 g sigma / sqrt(2 pi) per unit area (sigma = s / sqrt 2 per axis).
    sigma = opts.width_s / math.sqrt(2.0)
    spill = 2.0 * g * 4.0 * math.pi * sigma / math.sqrt(2.0 * math.pi)
    assert abs(quiet.blob_mass() - spill) < 0.25 * spill
    projection = opts.projection
    projection.reservoir_control = "exact"
    opts.projection = projection
    exact = otfp.Simulation(ball, data, opts)
    exact.start(otfp.ParticleSet(3), 0.0)
    assert len(exact.particles) > 0


def test_library_rows_are_the_command_line_series(tmp_path):
    """series.csv from library calls: the configuration's Simulation, the Crank reference from
    the domain's geometry, a RunRecorder after each step and SeriesLayout's rows give the text
    `otfp run` writes."""
    overrides = ["particles.n_inf=150", "run.t_end=0.25"]
    cli = otfp.load_config(otfp.example_config("sphere_dirichlet.toml"), overrides)
    assert cli.run(tmp_path / "out")["status"] == "completed"
    written = (tmp_path / "out" / "series.csv").read_text()

    run = otfp.load_config(otfp.example_config("sphere_dirichlet.toml"), overrides)
    d = run.description["derived"]
    sim = run.make_simulation()
    setup = otfp.ReferenceSetup()
    setup.center = d["center"]
    setup.M_inf = d["M_inf"]
    setup.t_end = 0.25
    setup.constant_dt = d["dt"]
    setup = otfp.complete_reference_geometry("crank_sphere", run.domain, [0], setup)
    reference = otfp.make_reference("crank_sphere", setup)
    options = otfp.RecorderOptions()
    options.center = d["center"]
    options.M_inf = d["M_inf"]
    options.J_inf = d["M_inf"] * run.domain.mean_square_distance(d["center"])
    assert options.J_inf == d["J_inf"]
    rows = otfp.RunRecorder(sim, options, reference)
    rows.step_dt = d["dt"]
    layout = otfp.SeriesLayout(True, reference.has_mass_blob_error, reference.columns)
    first = sim.initial_step
    text = layout.header + layout.row(rows.record(0, 0.0, None, first.inserted, first.removed))
    for k in range(1, d["n_steps"] + 1):
        step = sim.advance_to(k * d["dt"])
        text += layout.row(rows.record(k, step.t_end, step.diffusion, step.inserted, step.removed))
    assert text == written
    assert rows.record(d["n_steps"], 0.25).as_dict()["mass_ratio"] > 0.0
