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

Optional tables: ``[initial]`` (``x0``, ``v0``), ``[output]`` (``densities``: which of ``"x"``, ``"v"``,
``"joint"`` are stored, ``states``: whether the raw states are stored too, ``figures``, ``n_grid``).
Every error names the file and the key (``scene.toml: [model] r: must lie in [0, 1], got 1.5``).
"""

from __future__ import annotations

import dataclasses
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
METHODS = ("dpim", "monte_carlo")
DENSITIES = ("x", "v", "joint")


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
    """What a scene-file run stores: densities (``"x"``, ``"v"``, ``"joint"``), raw states, figures."""

    densities: tuple[str, ...] = DENSITIES
    states: bool = False
    figures: bool = True
    n_grid: int = 201


@dataclasses.dataclass(frozen=True)
class SceneFile:
    """A parsed scene file: the physics (``scene``), the methods to run and the outputs to store.

    ``table`` is the file's content with every default filled in (written to the run's metadata).
    """

    path: pathlib.Path
    scene: Any
    methods: tuple[Method, ...]
    outputs: Outputs
    table: dict


_SCHEMA = {
    "model": {"kind", "alpha", "gamma", "r", "barrier", "omega"},
    "noise": {"D"},
    "time": {"t_end", "dt", "save_at"},
    "initial": {"x0", "v0"},
    "method": {"name", "n_points", "n_samples", "seed"},
    "output": {"densities", "states", "figures", "n_grid"},
}
_REQUIRED = ("model", "noise", "time", "method")


class _Reader:
    """Typed access to one table of the file; every error names the file, the table and the key."""

    def __init__(self, path: pathlib.Path, name: str, table: Any):
        self.path, self.name = path, name
        if not isinstance(table, dict):
            self.fail(None, f"must be a table, got {_toml_type(table)}")
        unknown = sorted(set(table) - _SCHEMA[name])
        if unknown:
            self.fail(unknown[0], f"unknown key; allowed keys are {sorted(_SCHEMA[name])}")
        self.table = table

    def fail(self, key, message: str):
        where = f"[{self.name}]" if key is None else f"[{self.name}] {key}"
        raise SceneFileError(f"{self.path.name}: {where}: {message}")

    def number(self, key, default=None, *, low=None, high=None, low_open=False, allow_none=False):
        value = self.table.get(key, default)
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


def _toml_type(value) -> str:
    for kind, name in ((bool, "a boolean"), (str, "a string"), (int, "an integer"), (float, "a float")):
        if isinstance(value, kind):
            return name
    return {dict: "a table", list: "an array"}.get(type(value), type(value).__name__)


def load(path) -> SceneFile:
    """Read and check a scene file (see the module docstring for its keys).

    Raises:
        SceneFileError: one line naming the file and the key (missing file, TOML syntax, unknown key,
            wrong type, value out of range, or a scene the library rejects).
    """
    import jdpim

    path = pathlib.Path(path)
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
    tables = {name: _Reader(path, name, raw.get(name, {})) for name in _SCHEMA}

    m = tables["model"]
    kind = m.table.get("kind", "vibro_impact")
    if kind != "vibro_impact":
        m.fail("kind", f'must be "vibro_impact", got {kind!r}')
    model_args = {
        "alpha": m.number("alpha", NONE, low=0.0, allow_none=True),
        "gamma": m.number("gamma", NONE, low=0.0, allow_none=True),
        "r": m.number("r", low=0.0, high=1.0),
        "barrier": m.number("barrier", 0.0, allow_none=True),
        "omega": m.number("omega", 1.0, low=0.0, low_open=True),
    }
    D = tables["noise"].number("D", low=0.0)
    t = tables["time"]
    t_end = t.number("t_end", low=0.0, low_open=True)
    dt = t.number("dt", low=0.0, low_open=True)
    save_at = t.table.get("save_at", [t_end])
    if not isinstance(save_at, list) or not save_at:
        t.fail("save_at", f"must be a non-empty array of times in s, got {save_at!r}")
    save_at = [_Reader(path, "time", {"save_at": s}).number("save_at", low=0.0, high=t_end) for s in save_at]
    init = tables["initial"]
    x0 = init.number("x0", NONE, allow_none=True)
    v0 = init.number("v0", 0.0)

    me = tables["method"]
    names = me.choices("name", None, METHODS) if "name" in me.table else me.fail("name", "is required")
    seed = me.integer("seed", 0, low=0)
    for name, key in (("dpim", "n_samples"), ("monte_carlo", "n_points")):
        if key in me.table and name in names and len(names) == 1:
            me.fail(key, f"does not apply to method {name!r}")
    methods = tuple(
        Method("dpim", me.integer("n_points", 1000, low=2))
        if name == "dpim"
        else Method("monte_carlo", me.integer("n_samples", 10_000, low=2), seed)
        for name in names
    )
    o = tables["output"]
    outputs = Outputs(
        densities=o.choices("densities", list(DENSITIES), DENSITIES),
        states=o.boolean("states", False),
        figures=o.boolean("figures", True),
        n_grid=o.integer("n_grid", 201, low=2),
    )
    try:
        model = jdpim.VibroImpactOscillator(**model_args)
        scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), x0=x0, v0=v0, t_end=t_end, dt=dt, save_at=save_at)
    except (ValueError, TypeError) as err:
        key = re.match(r"[A-Za-z_]\w*", str(err)).group(0)
        table = next((n for n, keys in _SCHEMA.items() if key in keys), "time")
        raise SceneFileError(f"{path.name}: [{table}] {key}: {err}") from None
    table = {
        "model": {"kind": kind, **{k: (NONE if v is None else v) for k, v in model_args.items()}},
        "noise": {"D": D},
        "time": {"t_end": t_end, "dt": dt, "save_at": list(scene.save_at)},
        "initial": {"x0": NONE if x0 is None else x0, "v0": v0},
        "method": {
            "name": list(names),
            **{("n_points" if x.name == "dpim" else "n_samples"): x.n_paths for x in methods},
            "seed": seed,
        },
        "output": dataclasses.asdict(outputs),
    }
    return SceneFile(path, scene, methods, outputs, table)
