"""otfp: the optimal-transport finite-particle method of driven mass diffusion.

The C++ library bound with pybind11 (docs/python.md). A first program:

    import otfp
    run = otfp.load_config(otfp.example_config("sphere_dirichlet.toml"), ["run.t_end=0.1"])
    sim = run.make_simulation()
    sim.run_until(run.t_end, run.dt, lambda s, step: print(step))

Options classes take keyword arguments and check them at once:
ImplicitOptions(kappa=-1) raises ValueError naming the field.

A SimulationOptions built by hand has the papers' boundary treatment;
converging_options(...) gives the one `otfp run` uses (docs/python.md).
"""

from ._otfp import *  # noqa: F401,F403
from ._otfp import __version__, analytic  # noqa: F401
from . import _otfp

__all__ = [name for name in dir(_otfp) if not name.startswith("_")]


def _is_int(v):
    return isinstance(v, int) and not isinstance(v, bool)


# The bounds of the C++ integer types, as messages spell them.
_INT_BOUNDS_HI = ((2**64 - 1, "2**64 - 1"), (2**63 - 1, "2**63 - 1"), (2**32 - 1, "2**32 - 1"), (2**31 - 1, "2**31 - 1"))
_INT_BOUNDS_LO = ((-2**63, "-2**63"), (-2**31, "-2**31"), (0, "0"))


def _int_range(cls, base_setattr, key):
    """The range of an integer field: the widest bounds its C++ type accepts (tried on a fresh object)."""
    probe = cls()

    def accepts(v):
        try:
            base_setattr(probe, key, v)
            return True
        except TypeError:
            return False

    hi = next((text for v, text in _INT_BOUNDS_HI if accepts(v)), "?")
    lo = next((text for v, text in _INT_BOUNDS_LO if accepts(v)), "?")
    return lo, hi


def _options_init(cls):
    """Gives an options class keyword arguments, validation and a readable repr."""
    base_init = cls.__init__
    fields = tuple(cls._fields)

    base_setattr = cls.__setattr__

    def __setattr__(self, key, value):
        if key not in fields:
            raise ValueError(f"{cls.__name__}: no field '{key}' (fields: {', '.join(fields)})")
        current = getattr(self, key)
        try:
            if isinstance(value, dict) and hasattr(type(current), "_fields"):
                value = type(current)(**value)  # nested options given as a dict
            elif isinstance(value, str) and hasattr(type(current), "__members__"):
                value = type(current)(value)  # an enum by its name: the library's message
            base_setattr(self, key, value)
        except (TypeError, ValueError) as e:
            if isinstance(e, TypeError) and _is_int(value) and _is_int(current):
                lo, hi = _int_range(cls, base_setattr, key)  # out of the C++ type's range
                raise ValueError(f"{cls.__name__}.{key} = {value}: must be an integer in {lo} .. {hi}") from None
            if isinstance(e, TypeError):  # pybind11's overload listing: say it in one line
                raise ValueError(f"{cls.__name__}.{key} = {value!r}: expected {type(current).__name__}, "
                                 f"got {type(value).__name__}") from None
            first = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise ValueError(f"{cls.__name__}.{key}: {first}") from None

    def __init__(self, **kwargs):
        base_init(self)
        for key, value in kwargs.items():
            setattr(self, key, value)
        if kwargs and hasattr(self, "validate"):
            self.validate()

    def __repr__(self):
        parts = ", ".join(f"{f}={getattr(self, f)!r}" for f in fields)
        return f"{cls.__name__}({parts})"

    def __eq__(self, other):
        return type(self) is type(other) and repr(self) == repr(other)

    cls.__init__ = __init__
    cls.__setattr__ = __setattr__
    cls.__repr__ = __repr__
    cls.__eq__ = __eq__
    cls.__hash__ = None


for _name in dir(_otfp):
    _obj = getattr(_otfp, _name)
    if isinstance(_obj, type) and hasattr(_obj, "_fields"):
        _options_init(_obj)
_options_init(analytic.SlabBox)


def example_config(name):
    """The path of a configuration of the repository's examples/ (e.g. "sphere_dirichlet.toml"), shipped with
    the package so that programs run from any directory: otfp.load_config(otfp.example_config(name))."""
    import pathlib

    here = pathlib.Path(__file__).resolve().parent / "examples"
    path = here / name
    if not path.is_file():
        have = ", ".join(sorted(p.name for p in here.glob("*.toml"))) or "none"
        raise ValueError(f"example_config: no configuration '{name}' (shipped: {have})")
    return path


def converging_options(domain, boundary, n_inf, length_L, particle_mass, kappa=1.0, rho_ref=1.0,
                       stepper="implicit", kernel_tolerance=None):
    """SimulationOptions with the boundary treatment and parameters of `otfp run`'s default preset,
    treatment.preset = "converging" (docs/boundaries.md): image blobs at no-flux walls, the odd reservoir band
    one kernel cut-off wide outside Dirichlet faces, outlets that reach the nearest particles, and (36)-(40)
    from the true spacing (|Omega| / n_inf)^(1/d). SimulationOptions() alone is the papers' treatment
    (the b-thick Dirichlet layer), which does not converge to the analytic references (docs/validation.md).

    A shorthand for the library's otfp.setup_run (RunSetupOptions holds every input, setup_run(...).parameters
    the numbers (36)-(40) and the step). domain, boundary: as for Simulation (the reservoir is used when a patch
    is Dirichlet); n_inf: the particle count the spacing is for; length_L: L of the layer b = sqrt(L dr);
    particle_mass: m_p (the configuration's M_inf / n_inf). Returns a new SimulationOptions to adjust further."""
    o = RunSetupOptions()
    o.n_inf, o.length_L, o.particle_mass = n_inf, length_L, particle_mass
    o.kappa, o.rho_ref, o.stepper = kappa, rho_ref, stepper
    if kernel_tolerance is not None:
        o.kernel_tolerance = kernel_tolerance
    return setup_run(domain, boundary, o).options
