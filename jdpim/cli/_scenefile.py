r"""Scene files: a computation described in TOML, checked key by key before anything is traced.

.. code-block:: toml

    [model]
    kind = "vibro_impact"   # x'' + alpha x' + gamma x'^3 + omega^2 x = xi(t) on x >= barrier
    alpha = 0.03            # leave a damping term out (or write "none") and it is not traced at all
    gamma = 0.03
    r = 0.98
    [noise]
    D = 0.03
    [time]
    t_end = 200.0
    dt = 0.01
    save_at = [50.0, 200.0]
    [method]
    name = "dpim"           # "dpim", "monte_carlo", or a list of both
    n_points = 1000

``[method] forcing`` is Monte Carlo's forcing: ``"nodes"`` (the default, Gaussian values at the RK4 nodes drawn
inside the steps) or ``"spectral"`` (DPIM's spectral representation, with Gaussian coefficients).

Optional tables: ``[initial]`` (``x0``, ``v0``), ``[output]`` (``densities``: which of ``"x"``, ``"v"``,
``"joint"`` are stored, ``states``: whether the raw states are stored too, ``figures``, ``n_grid``),
``[reliability]`` (``quantity``: a coordinate, e.g. ``"x"``, or its magnitude ``"|x|"``; ``levels``: a number
or an array of them): first-passage probabilities ``P(max_{s <= t} quantity(s) > level)`` by every method at
every saved time (``jdpim.first_passage``).

``kind = "mdof"`` is ``jdpim.MDOFOscillator``, ``M q'' + C q' + K q = B xi(t)`` with constraints
``normal . q >= position``:

.. code-block:: toml

    [model]
    kind = "mdof"
    mass = [[1.0, 0.0], [0.0, 0.05]]        # M, (n, n) symmetric positive definite
    damping = [[0.02, 0.0], [0.0, 0.0]]     # C, (n, n), or "none" (the default)
    stiffness = [[1.0, 0.0], [0.0, 0.0]]    # K, (n, n), or "none" (the default)
    gains = [[1.0], [0.0]]                  # B, (n, m) for m noise sources
    [[model.constraints]]                   # any number of them, counted from 0
    normal = [-1.0, 1.0]
    position = -0.1
    r = 0.5

with ``[noise] D`` a number (one source) or an ``(m, m)`` matrix, ``[initial] x0``, ``v0`` arrays of ``n``
numbers (default: at rest at the model's start, 0 but for a harmonic filter), ``[output] densities`` the
coordinates whose marginals are stored (default: all of ``model.coordinates``) and ``[output] joint`` pairs of
them (``[["x1", "x2"]]``; default: none).

``kind`` may also name an example system, ``"impact_damper"``, ``"pounding_frame"``, ``"gear_pair"`` or
``"adjacent_buildings"``, whose function's arguments are the table's keys (each optional; the pairs of
``adjacent_buildings`` one value or an array of two). Models of several degrees of freedom take filters,
``[[model.filters]]`` with ``kind`` one of ``"kanai_tajimi"``, ``"clough_penzien"``, ``"first_order"``,
``"harmonic"`` and the function's arguments, appended in order. ``[noise] envelope`` modulates the noise
(``{ kind = "shinozuka_sato", b1 = 0.1, b2 = 0.5 }`` or ``{ kind = "jennings", t1 = 2.0, t2 = 6.0, c = 0.5 }``), or
shapes it by an evolutionary spectrum (``{ kind = "evolutionary_kanai_tajimi", omega_g = [[0, 20], [12, 3]],
zeta_g = 0.4, envelope = { kind = "shinozuka_sato" } }``, with ``[method] forcing = "spectral"``),
and a ``[fragility]`` table (``quantity``, ``level``, ``intensities``, ``reference``, ``confidence``) adds
``jdpim.fragility`` by the file's Monte Carlo method. ``[output] derived`` names linear combinations of coordinates
(``drift = {x2 = 1.0, x1 = -1.0}``) whose marginals are stored and which ``[reliability] quantity`` may name.

Every error names the file and the key (``scene.toml: [model] r: must lie in [0, 1], got 1.5``,
``damper.toml: [model] constraints[1].r: must lie in [0, 1], got 1.5``).
"""

from __future__ import annotations

import dataclasses
import inspect
import numbers
import pathlib
import re
import sys
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

NONE = "none"  # the TOML spelling of "this term is absent"
EXAMPLES = (
    "impact_damper",
    "pounding_frame",
    "gear_pair",
    "adjacent_buildings",
)  # jdpim's example systems, by their function's name
KINDS = ("vibro_impact", "mdof", *EXAMPLES)
FILTERS = (
    "kanai_tajimi",
    "clough_penzien",
    "first_order",
    "harmonic",
)  # [[model.filters]] kind -> jdpim.kanai_tajimi, ...
# [noise] envelope kind -> jdpim class; the evolutionary spectrum takes an envelope of the others
EVOLUTIONARY = "evolutionary_kanai_tajimi"
ENVELOPES = {"shinozuka_sato": "ShinozukaSato", "jennings": "Jennings", EVOLUTIONARY: "EvolutionaryKanaiTajimi"}
METHODS = ("dpim", "monte_carlo")
FORCINGS = ("nodes", "spectral")  # Monte Carlo's forcing: Gaussian values at the RK4 nodes, or DPIM's spectral one
DENSITIES = ("x", "v", "joint")  # [output] densities of one degree of freedom
NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")  # a coordinate's name: it names arrays and files


def excitation_of(forcing: str):
    """The scene's ``excitation`` for Monte Carlo's ``forcing`` (one of ``FORCINGS``): ``None`` for ``"nodes"``
    (each method's own: Gaussian nodes for Monte Carlo, the spectral representation for DPIM), or
    ``jdpim.SpectralRepresentation()`` for both methods."""
    import jdpim

    if forcing not in FORCINGS:
        raise ValueError(f"forcing must be one of {FORCINGS}, got {forcing!r}")
    return None if forcing == "nodes" else jdpim.SpectralRepresentation()


class SceneFileError(ValueError):
    """A scene file that cannot be used; the message is one line naming the file and the key."""


@dataclasses.dataclass(frozen=True)
class Method:
    """One method of a scene file: ``name`` (``"dpim"`` or ``"monte_carlo"``) and its number of paths."""

    name: str
    n_paths: int
    seed: int = 0

    def method(self, *, progress: bool | None = None):
        """The method object ``jdpim.solve`` runs: ``jdpim.DPIM`` or ``jdpim.MonteCarlo``."""
        import jdpim

        if self.name == "dpim":
            return jdpim.DPIM(n_points=self.n_paths, progress=progress)
        return jdpim.MonteCarlo(n_samples=self.n_paths, seed=self.seed, progress=progress)


@dataclasses.dataclass(frozen=True)
class Outputs:
    """What a scene-file run stores: the marginals of the coordinates ``marginals``, the joint densities of the
    coordinate pairs ``joint``, the marginals of the derived quantities ``derived``, raw states, figures, and the
    number of grid nodes per coordinate."""

    marginals: tuple[str, ...] = ("x", "v")
    joint: tuple[tuple[str, str], ...] = (("x", "v"),)
    derived: tuple[Linear, ...] = ()
    states: bool = False
    figures: bool = True
    n_grid: int = 201


@dataclasses.dataclass(frozen=True)
class Linear:
    """``sum_i c_i state[i]``, a quantity of ``[output.derived]`` (``gap = {x2 = 1.0, x1 = -1.0}``): a function of
    the state ``(n_state,)`` that is hashable, so ``jdpim.first_passage`` traces it as a static argument.

    ``terms`` are ``(index, coefficient)`` pairs, indices into ``model.coordinates``; ``str`` gives the name.
    """

    name: str
    terms: tuple[tuple[int, float], ...]

    def __call__(self, state):
        return sum(c * state[i] for i, c in self.terms)

    def __str__(self) -> str:
        return self.name


@dataclasses.dataclass(frozen=True)
class Magnitude:
    """``|q|``, the two-sided quantity ``"|name|"`` of ``[reliability]``, of a coordinate (``quantity``: its index
    in the state) or of a derived quantity (a :class:`Linear`); hashable like :class:`Linear`."""

    name: str
    quantity: int | Linear

    def __call__(self, state):
        return abs(self.quantity(state) if callable(self.quantity) else state[self.quantity])

    def __str__(self) -> str:
        return f"|{self.name}|"


@dataclasses.dataclass(frozen=True)
class Reliability:
    """``[reliability]``: the first passage of ``quantity`` (a coordinate's name, a :class:`Linear` or a
    :class:`Magnitude`; ``str`` gives its spelling in the file) above each of ``levels`` (``L`` floats)."""

    quantity: str | Linear | Magnitude
    levels: tuple[float, ...]


@dataclasses.dataclass(frozen=True)
class SceneFile:
    """A parsed scene file: the physics (``scene``), the methods to run and the outputs to store.

    ``table`` is the file's content with every default filled in (written to the run's metadata);
    ``reliability`` is ``None`` without a ``[reliability]`` table.
    """

    path: pathlib.Path
    scene: Any
    methods: tuple[Method, ...]
    outputs: Outputs
    table: dict
    reliability: Reliability | None = None
    fragility: FragilityCurve | None = None


@dataclasses.dataclass(frozen=True)
class FragilityCurve:
    """``[fragility]``: ``jdpim.fragility`` of ``quantity`` (as in :class:`Reliability`) above ``level`` at the
    intensity measures ``intensities`` (``I`` floats), in units of ``reference``, with intervals at ``confidence``."""

    quantity: str | Linear | Magnitude
    level: float
    intensities: tuple[float, ...]
    reference: float = 1.0
    confidence: float = 0.95


_MODEL_KEYS = {
    "vibro_impact": {"kind", "alpha", "gamma", "r", "barrier", "omega"},
    "mdof": {"kind", "mass", "damping", "stiffness", "gains", "names", "constraints", "filters"},
    "impact_damper": {"kind", "mass_ratio", "frequency", "damping_ratio", "clearance", "r", "filters"},
    "pounding_frame": {"kind", "n_storeys", "frequency", "damping_ratio", "gap", "r", "storey", "filters"},
    "gear_pair": {"kind", "mass_ratio", "drag", "bearing_damping", "backlash", "r", "filters"},
    "adjacent_buildings": {"kind", "n_storeys", "frequency", "damping_ratio", "mass", "gap", "r", "filters"},
}
_PAIR_KEYS = {"n_storeys", "frequency", "damping_ratio", "mass"}  # adjacent_buildings: one value for both, or two
_INTEGER_KEYS = {"n_storeys", "storey"}  # integers >= 1 of the example systems; every other key is a number
_CONSTRAINT_KEYS = {"normal", "position", "r"}
_FILTER_KEYS = {
    "kanai_tajimi": {"kind", "omega_g", "zeta_g", "influence"},
    "clough_penzien": {"kind", "omega_g", "zeta_g", "omega_f", "zeta_f", "influence"},
    "first_order": {"kind", "a"},
    "harmonic": {"kind", "amplitude", "frequency", "direction"},
}
_SCHEMA = {
    "model": set().union(*_MODEL_KEYS.values()),  # checked against the kind's keys once the kind is known
    "noise": {"D", "envelope"},
    "time": {"t_end", "dt", "save_at"},
    "initial": {"x0", "v0"},
    "method": {"name", "n_points", "n_samples", "seed", "forcing"},
    "output": {"densities", "joint", "derived", "states", "figures", "n_grid"},
    "reliability": {"quantity", "levels"},
    "fragility": {"quantity", "level", "intensities", "reference", "confidence"},
}
_ENVELOPE_KEYS = {
    "shinozuka_sato": {"kind", "b1", "b2"},
    "jennings": {"kind", "t1", "t2", "c"},
    EVOLUTIONARY: {"kind", "omega_g", "zeta_g", "omega_f", "zeta_f", "envelope"},
}
_LAWS = (("omega_g", 15.6), ("zeta_g", 0.6), ("omega_f", NONE), ("zeta_f", 0.6))  # EVOLUTIONARY's, with defaults
_REQUIRED = ("model", "noise", "time", "method")


class _Reader:
    """Typed access to one table of the file; every error names the file, the table and the key.

    ``keys``: the allowed keys (default: the table's in ``_SCHEMA``; ``None``: not checked here, see
    :meth:`only`). ``prefix`` goes before every key in messages (``"constraints[1]."``).
    """

    def __init__(self, path: pathlib.Path, name: str, table: Any, keys=(), prefix: str = ""):
        self.path, self.name, self.prefix = path, name, prefix
        if not isinstance(table, dict):
            self.fail(None, f"must be a table, got {_toml_type(table)}")
        self.table = table
        if keys is not None:
            self.only(keys or _SCHEMA[name])

    def only(self, keys) -> None:
        """Fail on the first key not in ``keys``."""
        unknown = sorted(set(self.table) - set(keys))
        if unknown:
            self.fail(unknown[0], f"unknown key; allowed keys are {sorted(keys)}")

    def fail(self, key, message: str):
        where = f"[{self.name}]" if key is None else f"[{self.name}] {self.prefix}{key}"
        raise SceneFileError(f"{self.path.name}: {where}: {message}")

    def number(self, key, default=None, **limits):
        """The number at ``key`` (see :meth:`real` for ``limits``)."""
        return self.real(key, self.table.get(key, default), **limits)

    def real(self, key, value, *, low=None, high=None, low_open=False, allow_none=False):
        """``value`` (of ``key``) as a finite float in the range given, or ``None`` for ``"none"`` where allowed."""
        if allow_none and (value is None or value == NONE):
            return None
        if value is None:
            self.fail(key, "is required")
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            hint = f' or "{NONE}"' if allow_none else ""
            self.fail(key, f"must be a number{hint}, got {_toml_type(value)} {value!r}")
        value = float(value)
        if value != value or value in (float("inf"), float("-inf")):
            self.fail(key, f"must be finite, got {value!r}")
        too_low = low is not None and (value <= low if low_open else value < low)
        if too_low or (high is not None and value > high):
            lo = "-inf" if low is None else f"{low:g}"
            hi = "inf" if high is None else f"{high:g}"
            self.fail(
                key,
                f"must lie in {'(' if low_open else '['}{lo}, {hi}{']' if high is not None else ')'}, got {value:g}",
            )
        return value

    def vector(self, key, length: int, default=None) -> list[float]:
        """An array of ``length`` numbers, one per coordinate."""
        value = self.table.get(key, default)
        if value is None:
            self.fail(key, "is required")
        if not isinstance(value, list) or len(value) != length:
            self.fail(key, f"must be an array of {length} numbers, one per coordinate, got {value!r}")
        return [self.real(f"{key}[{i}]", a) for i, a in enumerate(value)]

    def matrix(self, key, default=None, *, allow_none=False) -> list[list[float]] | None:
        """A matrix written as an array of equally long rows of numbers, or ``None`` for ``"none"`` where allowed.

        Its shape and properties are the library's to check (``jdpim.MDOFOscillator``, ``jdpim.WhiteNoise``).
        """
        value = self.table.get(key, default)
        if allow_none and (value is None or value == NONE):
            return None
        if value is None:
            self.fail(key, "is required")
        if not (isinstance(value, list) and value and all(isinstance(row, list) and row for row in value)):
            hint = f' or "{NONE}"' if allow_none else ""
            self.fail(key, f"must be a matrix, an array of rows of numbers{hint}, got {_toml_type(value)} {value!r}")
        if len({len(row) for row in value}) > 1:
            self.fail(key, f"must be a matrix: its rows have {[len(row) for row in value]} entries")
        return [[self.real(f"{key}[{i},{j}]", a) for j, a in enumerate(row)] for i, row in enumerate(value)]

    def integer(self, key, default=None, *, low: int):
        value = self.table.get(key, default)
        if value is None:
            self.fail(key, "is required")
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, f"must be an integer, got {_toml_type(value)} {value!r}")
        if value < low:
            self.fail(key, f"must be an integer >= {low}, got {value}")
        return value

    def boolean(self, key, default: bool) -> bool:
        value = self.table.get(key, default)
        if not isinstance(value, bool):
            self.fail(key, f"must be true or false, got {_toml_type(value)} {value!r}")
        return value

    def choices(self, key, default, allowed: tuple[str, ...]) -> tuple[str, ...]:
        value = self.table.get(key, default)
        items = [value] if isinstance(value, str) else value
        if not isinstance(items, (list, tuple)) or not items or not all(isinstance(v, str) for v in items):
            self.fail(key, f"must be a string or a non-empty list of strings from {list(allowed)}, got {value!r}")
        for v in items:
            if v not in allowed:
                self.fail(key, f"must be one of {list(allowed)}, got {v!r}")
        if len(set(items)) != len(items):
            self.fail(key, f"lists {value!r} with repeats")
        return tuple(items)

    def pairs(self, key, allowed: tuple[str, ...]) -> tuple[tuple[str, str], ...]:
        """An array of pairs of distinct names from ``allowed`` (``[["x1", "x2"]]``), without repeats; default none."""
        value = self.table.get(key, [])
        if not isinstance(value, list):
            self.fail(key, f'must be an array of pairs of coordinates, e.g. [["x1", "x2"]], got {value!r}')
        for i, pair in enumerate(value):
            if (
                not (isinstance(pair, list) and len(pair) == 2 and all(v in allowed for v in pair))
                or pair[0] == pair[1]
            ):
                self.fail(f"{key}[{i}]", f"must be a pair of distinct coordinates from {list(allowed)}, got {pair!r}")
        pairs = tuple((a, b) for a, b in value)
        if len(set(pairs)) != len(pairs):
            self.fail(key, f"lists {value!r} with repeats")
        return pairs


def _toml_type(value) -> str:
    for kind, name in ((bool, "a boolean"), (str, "a string"), (int, "an integer"), (float, "a float")):
        if isinstance(value, kind):
            return name
    return {dict: "a table", list: "an array"}.get(type(value), type(value).__name__)


def _library_error(path: pathlib.Path, err: Exception, table: str | None = None, prefix: str = "") -> SceneFileError:
    """A library's ``ValueError`` or ``TypeError`` in one line naming the key its message starts with.

    ``mass must be symmetric ...`` -> ``[model] mass: must be symmetric ...``; ``table`` defaults to the
    table that has the key; ``prefix`` goes before the key (``"constraints[1]."``).
    """
    message = str(err).splitlines()[0] if str(err) else type(err).__name__
    match = re.match(r"[A-Za-z_][\w.\[\]]*", message)
    key = match.group(0) if match else ""
    if table is None:
        base = re.match(r"\w*", key).group(0)
        table = next((name for name, keys in _SCHEMA.items() if base in keys), "time")
    if message[len(key) :].startswith(" must "):
        message = message[len(key) + 1 :]  # "mass must be ..." -> "must be ..." after the key
    return SceneFileError(f"{path.name}: [{table}] {prefix}{key}: {message}")


def _vibro_impact(m: _Reader):
    """``jdpim.VibroImpactOscillator`` of a ``kind = "vibro_impact"`` model table, and its parameters."""
    import jdpim

    args = {
        "alpha": m.number("alpha", NONE, low=0.0, allow_none=True),
        "gamma": m.number("gamma", NONE, low=0.0, allow_none=True),
        "r": m.number("r", low=0.0, high=1.0),
        "barrier": m.number("barrier", 0.0, allow_none=True),
        "omega": m.number("omega", 1.0, low=0.0, low_open=True),
    }
    try:
        model = jdpim.VibroImpactOscillator(**args)
    except (ValueError, TypeError) as err:
        raise _library_error(m.path, err, "model") from None
    return model, {"kind": "vibro_impact", **{k: (NONE if v is None else v) for k, v in args.items()}}


def _mdof(m: _Reader):
    """``jdpim.MDOFOscillator`` of a ``kind = "mdof"`` model table, and its parameters with defaults filled in.

    Types and the constraints' ranges are checked here; shapes, symmetry and definiteness by the library,
    whose messages are given under the key.
    """
    import jdpim

    mass = m.matrix("mass")
    n = len(mass)
    if len(mass[0]) != n:
        m.fail("mass", f"must be a square (n, n) matrix, got shape ({n}, {len(mass[0])})")
    matrices = {
        "mass": mass,
        "damping": m.matrix("damping", NONE, allow_none=True),
        "stiffness": m.matrix("stiffness", NONE, allow_none=True),
        "gains": m.matrix("gains"),
    }
    names = m.table.get("names")
    if names is not None and not (
        isinstance(names, list) and all(isinstance(s, str) and NAME.fullmatch(s) for s in names)
    ):
        m.fail("names", f"must be an array of names (a letter, then letters, digits or _), got {names!r}")
    tables = m.table.get("constraints", [])
    if not isinstance(tables, list) or not all(isinstance(c, dict) for c in tables):
        m.fail("constraints", f"must be an array of tables [[model.constraints]] (normal, position, r), got {tables!r}")
    constraints = []
    for j, table in enumerate(tables):
        c = _Reader(m.path, "model", table, _CONSTRAINT_KEYS, prefix=f"constraints[{j}].")
        args = {
            "normal": c.vector("normal", n),
            "position": c.number("position", 0.0),
            "r": c.number("r", low=0.0, high=1.0),
        }
        try:
            constraints.append(jdpim.Barrier(**args))
        except (ValueError, TypeError) as err:
            raise _library_error(m.path, err, "model", c.prefix) from None
    try:
        model = jdpim.MDOFOscillator(**matrices, constraints=tuple(constraints), names=names)
    except (ValueError, TypeError) as err:
        raise _library_error(m.path, err, "model") from None
    if len(set(model.coordinates)) != len(model.coordinates):  # e.g. names ["x", "v"]: the velocity of x is v
        m.fail("names", f"give the coordinates {list(model.coordinates)}, with repeats; choose other names")
    table = {
        "kind": "mdof",
        **{k: (NONE if v is None else v) for k, v in matrices.items()},
        "names": list(model.coordinates[:n]),
        "constraints": [
            {"normal": list(c.normal), "position": float(c.position), "r": float(c.r)} for c in constraints
        ],
    }
    return model, table


def _example(m: _Reader, kind: str):
    """``jdpim.<kind>(...)`` of an example system's model table (each key an argument of the function, optional),
    and its arguments with the defaults filled in. Types are checked here, ranges by the library."""
    import jdpim

    build = getattr(jdpim, kind)
    pairs = _PAIR_KEYS if kind == "adjacent_buildings" else set()
    args = {}
    for key, par in inspect.signature(build).parameters.items():
        if key in pairs and isinstance(m.table.get(key, par.default), (list, tuple)):
            args[key] = _pair(m, key, par.default)
        elif key in _INTEGER_KEYS:
            given = m.table.get(key, par.default)
            args[key] = None if given is None else m.integer(key, par.default, low=1)
        else:
            args[key] = m.number(key, par.default, allow_none=kind == "adjacent_buildings" and key == "gap")
    try:
        model = build(**args)
    except (ValueError, TypeError) as err:
        raise _library_error(m.path, err, "model") from None
    if kind == "pounding_frame" and args["storey"] is None:
        args["storey"] = args["n_storeys"]  # the top storey pounds by default
    return model, {
        "kind": kind,
        **{k: NONE if v is None else list(v) if isinstance(v, tuple) else v for k, v in args.items()},
    }


def _pair(m: _Reader, key: str, default) -> tuple:
    """``key`` of ``adjacent_buildings`` as two values, building ``a``'s and ``b``'s (an array of two; integers
    for ``n_storeys``)."""
    value = m.table.get(key, default)
    if len(value) != 2:
        m.fail(key, f"must be one value for both buildings or an array of two (building a, building b), got {value!r}")
    if key in _INTEGER_KEYS:
        for i, v in enumerate(value):
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                m.fail(f"{key}[{i}]", f"must be an integer >= 1, got {_toml_type(v)} {v!r}")
        return tuple(value)
    return tuple(m.real(f"{key}[{i}]", v) for i, v in enumerate(value))


def _envelope(noise: _Reader):
    """``[noise] envelope`` (``{ kind = "shinozuka_sato", b1 = 0.1, b2 = 0.5 }``, ``{ kind = "jennings", t1, t2,
    c }`` or ``{ kind = "evolutionary_kanai_tajimi", omega_g, zeta_g, omega_f, zeta_f, envelope }``) as the jdpim
    object, and its table with the defaults filled in; ``None`` (stationary noise) where the key is absent."""
    table = noise.table.get("envelope")
    if table is None:
        return None, None
    return _envelope_of(noise, table, "envelope.", tuple(ENVELOPES))


def _envelope_of(noise: _Reader, table, prefix: str, kinds: tuple):
    """The envelope (or evolutionary spectrum) of one of ``kinds`` that ``table`` (at ``prefix`` in ``[noise]``)
    describes, and its table with the defaults filled in."""
    import jdpim

    e = _Reader(noise.path, "noise", table if isinstance(table, dict) else {}, None, prefix=prefix)
    if not isinstance(table, dict):
        e.fail(None, f"{prefix[:-1]} must be a table {{ kind = one of {list(kinds)}, ... }}, got {table!r}")
    kind = table.get("kind")
    if kind not in kinds:
        e.fail("kind", f"must be one of {list(kinds)}, got {kind!r}")
    e.only(_ENVELOPE_KEYS[kind])
    cls = getattr(jdpim, ENVELOPES[kind])
    if kind == EVOLUTIONARY:
        echo = {name: _law(e, name, table.get(name, default)) for name, default in _LAWS}
        args = {name: None if value == NONE else _tuples(value) for name, value in echo.items()}
        if "envelope" in table:
            inner = tuple(k for k in ENVELOPES if k != EVOLUTIONARY)
            args["envelope"], echo["envelope"] = _envelope_of(noise, table["envelope"], prefix + "envelope.", inner)
    else:
        args = {f.name: e.number(f.name, f.default) for f in dataclasses.fields(cls)}
        echo = dict(args)
    try:
        return cls(**args), {"kind": kind, **echo}
    except (ValueError, TypeError) as err:
        raise _library_error(noise.path, err, "noise", e.prefix) from None


def _law(e: _Reader, key: str, value):
    """A parameter of the evolutionary Kanai-Tajimi spectrum: a number, ``"none"`` (``omega_f`` only), or a table
    ``[[t0, t1, ...], [p0, p1, ...]]`` interpolated linearly in time."""
    if value == NONE and key == "omega_f":
        return NONE
    if isinstance(value, list):
        if len(value) != 2 or not all(isinstance(row, list) for row in value):
            e.fail(key, f"must be a number or a table [[t0, t1, ...], [p0, p1, ...]], got {value!r}")
        return [[e.real(f"{key}[{i}][{j}]", v) for j, v in enumerate(row)] for i, row in enumerate(value)]
    return e.real(key, value)


def _tuples(value):
    """A :func:`_law` value as the library takes it: lists become tuples."""
    return tuple(tuple(row) for row in value) if isinstance(value, list) else value


def _filters(m: _Reader, model):
    """``model`` with the filters of ``[[model.filters]]`` appended in order (``jdpim.kanai_tajimi``,
    ``jdpim.first_order_filter``, ``jdpim.harmonic``), and their tables with the defaults filled in."""
    import jdpim

    tables = m.table.get("filters", [])
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        m.fail(
            "filters", f"must be an array of tables [[model.filters]] (kind = one of {list(FILTERS)}), got {tables!r}"
        )
    filled = []
    for i, table in enumerate(tables):
        f = _Reader(m.path, "model", table, None, prefix=f"filters[{i}].")
        kind = table.get("kind")
        if kind not in FILTERS:
            f.fail("kind", f"must be one of {list(FILTERS)}, got {kind!r}")
        f.only(_FILTER_KEYS[kind])
        build = jdpim.first_order_filter if kind == "first_order" else getattr(jdpim, kind)
        args = {}
        for key, par in list(inspect.signature(build).parameters.items())[1:]:
            if key in ("influence", "direction"):  # a vector over the coordinates so far, or the function's default
                args[key] = f.vector(key, model.dimension) if key in table else None
            else:
                args[key] = f.number(key, None if par.default is inspect.Parameter.empty else par.default)
        try:
            model = build(model, **args)
        except (ValueError, TypeError) as err:
            raise _library_error(m.path, err, "model", f.prefix) from None
        filled.append({"kind": kind, **{k: (NONE if v is None else v) for k, v in args.items()}})
    return model, filled


def _derived(o: _Reader, coords: tuple[str, ...]) -> tuple[Linear, ...]:
    """``[output] derived``: named linear combinations of the coordinates (``gap = {x2 = 1.0, x1 = -1.0}``)."""
    value = o.table.get("derived", {})
    example = "a table of names, each a table of coefficients by coordinate, e.g. gap = { x2 = 1.0, x1 = -1.0 }"
    if not isinstance(value, dict):
        o.fail("derived", f"must be {example}, got {_toml_type(value)} {value!r}")
    out = []
    for name, terms in value.items():
        if not NAME.fullmatch(name) or name in coords:
            o.fail(
                f"derived.{name}",
                f"must be a name (a letter, then letters, digits or _) other than the coordinates {list(coords)}",
            )
        if not isinstance(terms, dict) or not terms:
            o.fail(f"derived.{name}", f"must be {example}, got {_toml_type(terms)} {terms!r}")
        for coord in terms:
            if coord not in coords:
                o.fail(f"derived.{name}.{coord}", f"must be a coordinate of the model, one of {list(coords)}")
        out.append(Linear(name, tuple((coords.index(c), o.real(f"derived.{name}.{c}", a)) for c, a in terms.items())))
    return tuple(out)


def _intensity(noise: _Reader, n_sources: int):
    """``[noise] D`` of an MDOF model with ``n_sources`` columns of gains: an ``(m, m)`` matrix, or for one
    source a number >= 0."""
    value = noise.table.get("D")
    if n_sources == 1 and not isinstance(value, list):
        return noise.number("D", low=0.0)
    want = f"a ({n_sources}, {n_sources}) matrix, a row and a column per noise source (column of [model] gains)"
    if value is not None and not isinstance(value, list):
        noise.fail("D", f"must be {want}, got {_toml_type(value)} {value!r}")
    D = noise.matrix("D")
    if (len(D), len(D[0])) != (n_sources, n_sources):
        noise.fail("D", f"must be {want}, got shape ({len(D)}, {len(D[0])})")
    return D


def _quantity(r: _Reader, scene, derived: tuple[Linear, ...]) -> tuple:
    """``quantity`` of ``[reliability]`` or ``[fragility]``: ``(name, two_sided, named)``, a coordinate of the
    model or a quantity of ``derived`` (``named``: them by name), ``two_sided`` for ``"|q|"``."""
    coords, named = scene.model.coordinates, {q.name: q for q in derived}
    text = r.table.get("quantity")
    if text is None:
        r.fail("quantity", "is required")
    two_sided = isinstance(text, str) and len(text) > 2 and text[0] == text[-1] == "|"
    name = text[1:-1] if two_sided else text
    if not isinstance(text, str) or (name not in coords and name not in named):
        either = f", a quantity of [output] derived ({list(named)}), or the magnitude of either"
        also = either if named else ", or its magnitude"
        r.fail(
            "quantity",
            f'must be a coordinate of the model, one of {list(coords)}{also} ("|{coords[0]}|"), '
            f"got {_toml_type(text)} {text!r}",
        )
    return name, two_sided, named


def _quantity_of(scene, name: str, two_sided: bool, named: dict):
    """The quantity ``jdpim.first_passage`` takes: a coordinate's name, a :class:`Linear` or a :class:`Magnitude`."""
    if name in named:
        return Magnitude(name, named[name]) if two_sided else named[name]
    return Magnitude(name, scene.model.coordinates.index(name)) if two_sided else name


def _check_levels(r: _Reader, key: str, scene, name: str, two_sided: bool, named: dict, levels) -> None:
    """``levels`` of a coordinate above its barrier (``jdpim.first_passage``'s check, its message under ``key``)."""
    from jdpim.reliability._first_passage import checked_levels

    if name not in named and not two_sided:
        try:
            checked_levels(scene, name, levels)
        except ValueError as err:
            r.fail(key, str(err).splitlines()[0])


def _reliability(r: _Reader, scene, derived: tuple[Linear, ...] = ()) -> Reliability:
    """``[reliability]`` of ``scene``: a coordinate of its model, a quantity of ``derived`` or ``"|q|"`` of either,
    and levels above the coordinate's barrier (the library's check, ``jdpim.first_passage``'s message under the
    key) or, for a magnitude, above 0."""
    name, two_sided, named = _quantity(r, scene, derived)
    above_zero = {"low": 0.0, "low_open": True} if two_sided else {}  # |c| >= 0 exceeds a level <= 0 at once
    value = r.table.get("levels")
    if value is None:
        r.fail("levels", "is required")
    if isinstance(value, list) and value:
        levels = tuple(r.real(f"levels[{i}]", a, **above_zero) for i, a in enumerate(value))
    elif isinstance(value, numbers.Real) and not isinstance(value, bool):
        levels = (r.real("levels", value, **above_zero),)
    else:
        r.fail("levels", f"must be a number or a non-empty array of numbers, got {_toml_type(value)} {value!r}")
    _check_levels(r, "levels", scene, name, two_sided, named, levels)
    return Reliability(_quantity_of(scene, name, two_sided, named), levels)


def _fragility(f: _Reader, scene, derived: tuple[Linear, ...], names: tuple[str, ...]) -> FragilityCurve:
    """``[fragility]`` of ``scene``: the quantity as in ``[reliability]``, one ``level``, at least two increasing
    positive ``intensities``, ``reference`` > 0 and ``confidence`` in (0, 1); it needs the Monte Carlo method."""
    if "monte_carlo" not in names:
        f.fail(None, 'needs the method "monte_carlo" ([method] name): the fragility counts are binomial')
    name, two_sided, named = _quantity(f, scene, derived)
    level = f.number("level", low=0.0 if two_sided else None, low_open=True)
    _check_levels(f, "level", scene, name, two_sided, named, (level,))
    value = f.table.get("intensities")
    if not isinstance(value, list) or len(value) < 2:
        f.fail("intensities", f"must be an array of at least two increasing numbers > 0, got {value!r}")
    intensities = tuple(f.real(f"intensities[{i}]", a, low=0.0, low_open=True) for i, a in enumerate(value))
    if any(b <= a for a, b in zip(intensities, intensities[1:], strict=False)):
        f.fail("intensities", f"must increase, got {list(intensities)}")
    reference = f.number("reference", 1.0, low=0.0, low_open=True)
    confidence = f.number("confidence", 0.95, low=0.0, low_open=True, high=1.0)
    if confidence == 1.0:
        f.fail("confidence", "must lie in (0, 1), got 1")
    return FragilityCurve(_quantity_of(scene, name, two_sided, named), level, intensities, reference, confidence)


def _read(path: pathlib.Path) -> dict:
    """The file's tables, once it reads as TOML with no unknown table and every table of ``_REQUIRED``."""
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise SceneFileError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise SceneFileError(f"{path}: cannot be read ({err})") from None
    except tomllib.TOMLDecodeError as err:
        raise SceneFileError(f"{path.name}: not valid TOML: {err}") from None
    unknown = sorted(set(raw) - set(_SCHEMA))
    if unknown:
        raise SceneFileError(f"{path.name}: [{unknown[0]}]: unknown table; allowed tables are {sorted(_SCHEMA)}")
    for name in _REQUIRED:
        if name not in raw:
            raise SceneFileError(f"{path.name}: [{name}]: missing table")
    return raw


def _model(m: _Reader):
    """The model of ``[model]`` (``kind`` one of ``KINDS``, ``"vibro_impact"`` by default) with its filters
    appended, and its table with the defaults filled in."""
    kind = m.table.get("kind", "vibro_impact")
    if kind not in KINDS:
        m.fail("kind", f"must be one of {list(KINDS)}, got {kind!r}")
    m.only(_MODEL_KEYS[kind])
    if kind == "vibro_impact":
        return _vibro_impact(m)
    model, table = _mdof(m) if kind == "mdof" else _example(m, kind)
    model, table["filters"] = _filters(m, model)
    return model, table


def _noise(noise: _Reader, model, mdof: bool):
    """``[noise]``: the intensity ``D`` (a number, or for several degrees of freedom see :func:`_intensity`), the
    envelope (``None``: stationary), and the table with the defaults filled in."""
    D = _intensity(noise, model.n_sources) if mdof else noise.number("D", low=0.0)
    envelope, envelope_table = _envelope(noise)
    return D, envelope, {"D": D, **({"envelope": envelope_table} if envelope is not None else {})}


def _time(t: _Reader) -> tuple[float, float, list[float]]:
    """``[time]``: ``t_end`` > 0 and ``dt`` > 0 (s), and the times ``save_at`` in [0, t_end] (default ``[t_end]``)."""
    t_end = t.number("t_end", low=0.0, low_open=True)
    dt = t.number("dt", low=0.0, low_open=True)
    save_at = t.table.get("save_at", [t_end])
    if not isinstance(save_at, list) or not save_at:
        t.fail("save_at", f"must be a non-empty array of times in s, got {save_at!r}")
    return t_end, dt, [t.real("save_at", s, low=0.0, high=t_end) for s in save_at]


def _initial(init: _Reader, model, mdof: bool):
    """``[initial]``: ``x0`` and ``v0``, numbers for one degree of freedom (``x0`` ``None`` by default: at the
    barrier, or 0), arrays of ``n`` numbers for several (``x0`` ``None`` by default: at rest at the model's start,
    as ``jdpim.Scene`` without ``x0``, which compiles the same programs)."""
    if not mdof:
        return init.number("x0", NONE, allow_none=True), init.number("v0", 0.0)
    n = model.dimension
    return (init.vector("x0", n) if "x0" in init.table else None), init.vector("v0", n, [0.0] * n)


def _start(model) -> list[float]:
    """Where the paths of several degrees of freedom start without ``x0``: the model's start (0, or 1 for a
    harmonic filter)."""
    return list(model.start or (0.0,) * model.dimension)


def _methods(me: _Reader) -> tuple[tuple[Method, ...], str, dict]:
    """``[method]``: the methods in the order named, Monte Carlo's forcing (one of ``FORCINGS``), and the table
    with the defaults filled in."""
    names = me.choices("name", None, METHODS) if "name" in me.table else me.fail("name", "is required")
    seed = me.integer("seed", 0, low=0)
    forcing = me.table.get("forcing", FORCINGS[0])
    if not isinstance(forcing, str) or forcing not in FORCINGS:
        me.fail("forcing", f"must be one of {list(FORCINGS)}, got {forcing!r}")
    for name, key in (("dpim", "n_samples"), ("monte_carlo", "n_points"), ("dpim", "forcing")):
        if key in me.table and name in names and len(names) == 1:
            me.fail(key, f"does not apply to method {name!r}")
    methods = tuple(
        Method("dpim", me.integer("n_points", 1000, low=2))
        if name == "dpim"
        else Method("monte_carlo", me.integer("n_samples", 10_000, low=2), seed)
        for name in names
    )
    table = {
        "name": list(names),
        **{("n_points" if x.name == "dpim" else "n_samples"): x.n_paths for x in methods},
        "seed": seed,
        **({"forcing": forcing} if "monte_carlo" in names else {}),
    }
    return methods, forcing, table


def _outputs(o: _Reader, model, mdof: bool) -> tuple[Outputs, dict]:
    """``[output]``: what the run stores, and the table with the defaults filled in (one degree of freedom:
    ``densities`` from ``DENSITIES``; several: the coordinates' marginals and the pairs ``joint``)."""
    coords = model.coordinates
    if mdof:
        densities, joint = o.choices("densities", list(coords), coords), o.pairs("joint", coords)
        marginals = densities
    else:
        if "joint" in o.table:
            o.fail("joint", 'applies to kind = "mdof"; for one degree of freedom list "joint" in densities')
        densities = o.choices("densities", list(DENSITIES), DENSITIES)
        marginals = tuple(d for d in densities if d != "joint")
        joint = (("x", "v"),) if "joint" in densities else ()
    outputs = Outputs(
        marginals=marginals,
        joint=joint,
        derived=_derived(o, coords),
        states=o.boolean("states", False),
        figures=o.boolean("figures", True),
        n_grid=o.integer("n_grid", 201, low=2),
    )
    return outputs, {
        "densities": list(densities),
        **({"joint": [list(p) for p in joint]} if mdof else {}),
        **(
            {"derived": {q.name: {coords[i]: c for i, c in q.terms} for q in outputs.derived}}
            if outputs.derived
            else {}
        ),
        "states": outputs.states,
        "figures": outputs.figures,
        "n_grid": outputs.n_grid,
    }


def _questions(raw: dict, tables: dict, scene, derived: tuple[Linear, ...], names: tuple[str, ...]) -> tuple:
    """The questions of the file, ``[reliability]`` and ``[fragility]`` (each ``None`` where the file has no such
    table), and their tables as stored, with the defaults filled in."""
    reliability = _reliability(tables["reliability"], scene, derived) if "reliability" in raw else None
    fragility = _fragility(tables["fragility"], scene, derived, names) if "fragility" in raw else None
    table = {}
    if reliability is not None:
        table["reliability"] = {"quantity": str(reliability.quantity), "levels": list(reliability.levels)}
    if fragility is not None:
        table["fragility"] = {
            "quantity": str(fragility.quantity),
            **{k: getattr(fragility, k) for k in ("level", "reference", "confidence")},
            "intensities": list(fragility.intensities),
        }
    return reliability, fragility, table


def load(path) -> SceneFile:
    """Read and check a scene file (see the module docstring for its keys).

    Raises:
        SceneFileError: one line naming the file and the key (missing file, TOML syntax, unknown key,
            wrong type, value out of range, or a scene the library rejects).
    """
    import jdpim

    path = pathlib.Path(path)
    raw = _read(path)
    tables = {name: _Reader(path, name, raw.get(name, {}), keys=None if name == "model" else ()) for name in _SCHEMA}
    model, model_table = _model(tables["model"])
    mdof = model_table["kind"] != "vibro_impact"  # several degrees of freedom: a jdpim.MDOFOscillator
    D, envelope, noise_table = _noise(tables["noise"], model, mdof)
    t_end, dt, save_at = _time(tables["time"])
    x0, v0 = _initial(tables["initial"], model, mdof)
    methods, forcing, method_table = _methods(tables["method"])
    outputs, output_table = _outputs(tables["output"], model, mdof)
    if (
        isinstance(envelope, jdpim.AbstractEvolutionarySpectrum)
        and forcing == "nodes"
        and "monte_carlo" in method_table["name"]
    ):
        tables["method"].fail(
            "forcing",
            'must be "spectral" under an evolutionary [noise] envelope (the Gaussian nodes carry no spectrum)',
        )
    try:
        noise = jdpim.WhiteNoise(D=D, envelope=envelope)
        excitation = excitation_of(forcing)
        scene = jdpim.Scene(
            model, noise=noise, x0=x0, v0=v0, t_end=t_end, dt=dt, save_at=save_at, excitation=excitation
        )
    except (ValueError, TypeError) as err:
        raise _library_error(path, err) from None
    reliability, fragility, question_tables = _questions(
        raw, tables, scene, outputs.derived, tuple(method_table["name"])
    )
    table = {
        "model": model_table,
        "noise": noise_table,
        "time": {"t_end": t_end, "dt": dt, "save_at": list(scene.save_at)},
        "initial": {"x0": x0 if x0 is not None else _start(model) if mdof else NONE, "v0": v0},
        "method": method_table,
        "output": output_table,
        **question_tables,
    }
    return SceneFile(path, scene, methods, outputs, table, reliability, fragility)
