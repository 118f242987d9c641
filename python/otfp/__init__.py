"""otfp: the optimal-transport finite-particle method of driven mass diffusion.

The C++ library bound with pybind11 (docs/python.md). A first program:

    import otfp
    run = otfp.load_config("examples/sphere_dirichlet.toml", ["run.t_end=0.1"])
    sim = run.make_simulation()
    sim.run_until(run.t_end, run.dt, lambda s, step: print(step))

Options classes take keyword arguments and check them at once:
ImplicitOptions(kappa=-1) raises ValueError naming the field.
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
