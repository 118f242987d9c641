"""otfp.converging_options gives the options `otfp run` builds under its
default treatment.preset = "converging", and otfp.example_config finds the
shipped configurations from any directory."""
import os

import pytest

import otfp


def cli_options(name, overrides):
    run = otfp.load_config(otfp.example_config(name), overrides)
    return run, run.make_simulation().options


def same_run_fields(mine, theirs):
    """The fields the command line sets from its run section (not from the preset) copied over."""
    mine.time_control = theirs.time_control
    mine.seed = theirs.seed
    mine.max_particles = theirs.max_particles
    return mine


@pytest.mark.parametrize("extra", [[], ["solver.stepper=explicit"], ["particles.n_inf=333", "physics.kappa=0.5"]])
def test_converging_options_equal_the_command_line_preset_on_the_sphere(extra):
    run, theirs = cli_options("sphere_dirichlet.toml", ["particles.n_inf=150"] + extra)
    d = run.description
    n_inf = d["config"]["particles"]["n_inf"]
    kappa = d["config"]["physics"]["kappa"]
    boundary = [otfp.BoundaryData(patch=0, kind="dirichlet", value=0.238732)]
    mine = otfp.converging_options(run.domain, boundary, n_inf=n_inf, length_L=1.0, particle_mass=run.M_inf / n_inf,
                                   kappa=kappa, stepper=d["config"]["solver"]["stepper"])
    assert str(theirs.projection.dirichlet_mode) == "reservoir"  # the preset is what is compared
    assert repr(same_run_fields(mine, theirs)) == repr(theirs)
    # The library's default is the papers' layer: not what the command line runs.
    assert otfp.SimulationOptions().projection.dirichlet_mode != theirs.projection.dirichlet_mode


def test_converging_options_equal_the_command_line_preset_on_a_box_with_walls():
    run, theirs = cli_options("box_mixed.toml", [])
    d = run.description
    boundary = [otfp.BoundaryData(patch=b["id"], kind=b["kind"], value=b["value"])
                for b in d["derived"]["patches"] if b["kind"] != "no_flux"] if "patches" in d["derived"] else None
    assert boundary is not None, sorted(d["derived"])
    mine = otfp.converging_options(run.domain, boundary, n_inf=d["config"]["particles"]["n_inf"],
                                   length_L=d["derived"]["length_L"], particle_mass=d["derived"]["particle_mass"],
                                   kappa=d["config"]["physics"]["kappa"])
    assert str(theirs.no_flux) == "images"
    assert repr(same_run_fields(mine, theirs)) == repr(theirs)


def test_example_config_from_another_directory(tmp_path):
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        run = otfp.load_config(otfp.example_config("sphere_dirichlet.toml"), ["particles.n_inf=150"])
    finally:
        os.chdir(cwd)
    assert run.M_inf == 1.0
    with pytest.raises(ValueError, match=r"example_config: no configuration 'nothere.toml' \(shipped: .*sphere_dirichlet"):
        otfp.example_config("nothere.toml")


def test_str_of_an_enum_is_its_configuration_name():
    assert str(otfp.PatchKind.Dirichlet) == "dirichlet"
    assert str(otfp.DirichletMode.Reservoir) == "reservoir"
    assert str(otfp.NeumannOutflow.NearestParticles) == "nearest_particles"
    for name in ("bdf2", "euler"):
        assert str(otfp.TimeScheme(name)) == name
    assert repr(otfp.PatchKind.Dirichlet) == "<PatchKind.Dirichlet: 1>" or "PatchKind.Dirichlet" in repr(
        otfp.PatchKind.Dirichlet)


def test_fill_and_mass_rules_of_the_library_give_the_command_line_numbers():
    """pipe_neumann: no Dirichlet data, a Neumann inlet, a fill of a given mass and M_inf
    given; the library's InitialFillRule gives the command line's net inflow, M_inf, m_p and
    fill count, and the domain's measures the J_inf the command line reports."""
    run = otfp.load_config(otfp.example_config("pipe_neumann.toml"), [])
    d = run.description
    pa = d["config"]["particles"]
    boundary = [otfp.BoundaryData(patch=b["id"], kind=b["kind"], value=b["value"])
                for b in d["derived"]["patches"] if b["kind"] != "no_flux"]
    o = otfp.RunSetupOptions()
    o.n_inf = pa["n_inf"]
    o.kappa = d["config"]["physics"]["kappa"]
    o.t_end = d["config"]["run"]["t_end"]
    o.length_L = d["derived"]["length_L"]
    o.fill.filled = True
    o.fill.mass = pa["fill_mass"]
    assert otfp.setup_run(run.domain, boundary, o).parameters.M_inf_rule == otfp.MassRule.FillMass
    o.M_inf = d["config"]["diagnostics"]["M_inf"]
    p = otfp.setup_run(run.domain, boundary, o).parameters
    assert p.M_inf_rule == otfp.MassRule.Given
    assert (p.M_inf, p.particle_mass) == (d["derived"]["M_inf"], d["derived"]["particle_mass"])
    assert p.neumann_net_inflow == d["derived"]["neumann_net_inflow"]
    assert p.fill_count == d["derived"]["fill_count"]
    center = run.domain.inertia_center
    assert list(center) == d["derived"]["center"]
    assert d["derived"]["J_inf"] == d["derived"]["M_inf"] * run.domain.mean_square_distance(center)
