r"""Results on disk: ``result.save(path)`` and ``jdpim.load(path)``, and labelled arrays (``result.to_xarray()``).

A file is a NumPy ``.npz`` archive (a zip of ``.npy`` arrays) that ``numpy.load(path, allow_pickle=False)``
opens. Every array of the result, the scene and the method is one entry, named by where it sits
(``result/states``, ``result/derivative/alpha``); the entry ``jdpim`` holds a JSON document (a 0-d text array) with
the file format, the versions that wrote it and the objects' structure: each object is
``{"class": name, "fields": {...}}``, arrays are ``{"array": entry}`` (``{"scalar": entry}`` for a NumPy
scalar), tuples ``{"tuple": [...]}``, dicts ``{"dict": [[key, value], ...]}`` and non-finite floats
``{"float": "nan"}``; other numbers, text and lists are themselves. Loading rebuilds objects only from an
explicit list of jdpim's own classes (``_classes``), by their constructors: no pickle, no import, no code from
the file runs. Arrays come back as NumPy
arrays with their dtypes and bits; every jdpim function takes them.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
import numbers
import os
import platform
import warnings
from typing import Any

import numpy as np

from ._version import __version__

FORMAT = 1  # the layout of the JSON document; a reader refuses a later one
ENTRY = "jdpim"  # the archive entry that holds the JSON document


class PersistenceWarning(UserWarning):
    """A saved file is incomplete (a scene or method holding Python functions) or from another jdpim version."""


@dataclasses.dataclass(frozen=True)
class Metadata:
    """What a file stores beside its result (``jdpim.load(path, metadata=True)``).

    Attributes:
        result_type: the result's class name (``"Result"``, ``"GridResult"``, ``"FirstPassage"``, ...).
        scene: the :class:`jdpim.Scene` given to ``save``, or ``None`` (none given, or not restorable).
        method: the method given to ``save`` (``jdpim.DPIM(...)``, ...), or ``None``.
        scene_text, method_text: their ``repr`` (also for objects that are not restored), or ``None``.
        versions: ``{"jdpim", "jax", "numpy", "python", "backend", "devices"}`` of the process that saved it.
        created: when it was saved, ISO 8601 in UTC.
        format: the file format's version.
    """

    result_type: str
    scene: Any
    method: Any
    scene_text: str | None
    method_text: str | None
    versions: dict
    created: str
    format: int


def versions() -> dict:
    """Versions of jdpim, JAX, NumPy and Python, and the JAX backend (for the metadata of every output)."""
    import jax

    return {
        "jdpim": __version__,
        "jax": jax.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
        "backend": jax.default_backend(),
        "devices": len(jax.devices()),
    }


_KNOWN: dict[str, type] = {}


def allow(*classes: type) -> None:
    """Let files name ``classes`` (results, scenes and their parts, methods, estimators): ``jdpim/__init__.py``
    lists them; a file naming any other class is refused."""
    _KNOWN.update({k.__name__: k for k in classes})


def _classes() -> dict[str, type]:
    """The classes a file may name, by name."""
    return _KNOWN


RESULTS = (
    "Result", "GridResult", "FirstPassage", "ImpactStatistics", "Sensitivity",
    "ResponseMoments", "ResponseSpectrum", "ResponseAutocorrelation", "Fragility", "Tracked", "PeakDistribution",
)  # fmt: skip


class _NotStored(Exception):
    """A value with no file form (a Python function, a device, a user class), found at ``where``."""

    def __init__(self, where: str, value: Any):
        super().__init__(f"{where} is a {type(value).__name__}")


class _Writer:
    """Encodes objects as JSON-ready values, collecting their arrays under the names of where they sit."""

    def __init__(self, classes: dict[str, type]):
        self.classes = classes
        self.arrays: dict[str, np.ndarray] = {}

    def array(self, value, where: str) -> str:
        arr = np.asarray(value)
        if arr.dtype.hasobject or arr.dtype.kind == "V":
            raise _NotStored(where, value)
        name, k = where, 1
        while name in self.arrays or name == ENTRY:
            name, k = f"{where}#{k}", k + 1
        self.arrays[name] = arr
        return name

    def encode(self, value, where: str):
        import jax

        if isinstance(value, jax.core.Tracer):
            raise TypeError(f"save needs concrete values, got a traced array at {where}: save outside jax.jit")
        if value is None or isinstance(value, (bool, str)):
            return value
        if isinstance(value, np.generic):  # before float and int: a NumPy scalar keeps its dtype
            return {"scalar": self.array(value, where)}
        if isinstance(value, numbers.Integral):
            return int(value)
        if isinstance(value, float):
            return value if math.isfinite(value) else {"float": repr(value)}
        if isinstance(value, (np.ndarray, jax.Array)):
            return {"array": self.array(value, where)}
        if isinstance(value, tuple):
            return {"tuple": [self.encode(v, f"{where}/{i}") for i, v in enumerate(value)]}
        if isinstance(value, list):
            return [self.encode(v, f"{where}/{i}") for i, v in enumerate(value)]
        if isinstance(value, dict):
            return {"dict": [[self.encode(k, where), self.encode(v, f"{where}/{k}")] for k, v in value.items()]}
        name = type(value).__name__
        if self.classes.get(name) is type(value):
            fields = {
                f.name: self.encode(getattr(value, f.name), f"{where}/{f.name}")
                for f in dataclasses.fields(value)
                if f.init
            }
            return {"class": name, "fields": fields}
        raise _NotStored(where, value)


def save(obj, path, *, scene=None, method=None) -> None:
    """Write ``obj`` (a jdpim result) to ``path`` with ``scene``, ``method`` and the versions as metadata.

    ``path`` is written as given (the suffix ``.npz`` is customary). A scene or method that holds Python
    functions (an :class:`jdpim.Oscillator`'s ``g``, ``f``, ``h``, a ``PathIntegration(initial=...)``) or
    devices cannot be stored: it is kept as its ``repr`` only, with a :class:`PersistenceWarning`.
    """
    classes = _classes()
    if type(obj).__name__ not in RESULTS or classes[type(obj).__name__] is not type(obj):
        raise TypeError(f"save takes a jdpim result ({', '.join(RESULTS)}), got {type(obj).__name__}")
    if scene is not None and not isinstance(scene, classes["Scene"]):
        raise TypeError(f"scene must be the jdpim.Scene the result came from, or None; got {type(scene).__name__}")
    if method is not None and getattr(method, "name", None) != obj.method:
        raise ValueError(f"method must be the method the result came from ({obj.method!r}) or None, got {method!r}")
    writer = _Writer(classes)
    doc = {
        "format": FORMAT,
        "type": type(obj).__name__,
        "versions": versions(),
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }
    try:
        doc["result"] = writer.encode(obj, "result")
    except _NotStored as e:  # a result holds only arrays, numbers, text and jdpim settings
        raise TypeError(f"cannot save this {type(obj).__name__}: {e}") from None
    lost, why = [], []
    for key, value in (("scene", scene), ("method", method)):
        doc[f"{key}_text"] = None if value is None else repr(value)
        kept = dict(writer.arrays)
        try:
            doc[key] = writer.encode(value, key)
        except _NotStored as e:
            writer.arrays = kept  # none of its arrays
            doc[key] = None
            lost.append(key)
            why.append(str(e))
    if lost:
        warnings.warn(
            f"{os.fspath(path)}: the {' and the '.join(lost)} cannot be stored ({'; '.join(why)}): the file keeps "
            f"{'its' if len(lost) == 1 else 'their'} repr only (Metadata.{'_text, '.join(lost)}_text)",
            PersistenceWarning,
            stacklevel=3,
        )
    text = np.array(json.dumps(doc, allow_nan=False))
    with open(path, "wb") as fh:  # a file object: numpy appends no suffix
        np.savez_compressed(fh, **{ENTRY: text}, **writer.arrays)


def _decode(node, arrays, classes: dict[str, type], written: str):
    """The value of a JSON node (see the module doc), rebuilt from ``arrays`` and ``classes`` only."""
    if node is None or isinstance(node, (bool, int, float, str)):
        return node
    if isinstance(node, list):
        return [_decode(n, arrays, classes, written) for n in node]
    if "array" in node:
        return arrays[node["array"]]
    if "scalar" in node:
        return arrays[node["scalar"]][()]
    if "float" in node:
        return float(node["float"])
    if "tuple" in node:
        return tuple(_decode(n, arrays, classes, written) for n in node["tuple"])
    if "dict" in node:
        return {_decode(k, arrays, classes, written): _decode(v, arrays, classes, written) for k, v in node["dict"]}
    name = node["class"]
    if name not in classes:
        raise ValueError(f"the file, written by jdpim {written}, names a class {name!r} that this jdpim does not know")
    fields = {k: _decode(v, arrays, classes, written) for k, v in node["fields"].items()}
    if name == "Result" and "independent" not in fields:  # a file from before Result.independent
        kinds = {getattr(c, "name", None): c for c in classes.values() if hasattr(c, "independent")}
        fields["independent"] = getattr(kinds.get(fields.get("method")), "independent", False)
    try:
        return classes[name](**fields)
    except TypeError as e:
        raise ValueError(f"the file's {name}, written by jdpim {written}, does not fit this jdpim's: {e}") from None


def load(path, *, metadata: bool = False):
    """The result saved at ``path`` (``result.save(path)``); with ``metadata=True``, ``(result, Metadata)``.

    Nothing in the file is executed (``allow_pickle=False``; objects are rebuilt from jdpim's own classes).
    A file of a later format is refused; one written by another jdpim version gives a
    :class:`PersistenceWarning`. Arrays are NumPy arrays, bit for bit and dtype for dtype as saved.
    """
    name = os.fspath(path)
    with np.load(path, allow_pickle=False) as npz:
        if ENTRY not in npz.files:
            raise ValueError(f"{name} is not a jdpim result file (no {ENTRY!r} entry): write one with result.save")
        doc = json.loads(str(npz[ENTRY]))
        arrays = {k: npz[k] for k in npz.files if k != ENTRY}
    if not isinstance(doc, dict):
        raise ValueError(f"{name}: malformed jdpim document (a JSON {type(doc).__name__}, not an object)")
    written = doc.get("versions", {}).get("jdpim", "unknown")
    if doc.get("format") != FORMAT:
        raise ValueError(
            f"{name} has file format {doc.get('format')!r} (jdpim {written}); this jdpim ({__version__}) "
            f"reads format {FORMAT}: load it with jdpim {written}"
        )
    if written != __version__:
        warnings.warn(
            f"{name} was written by jdpim {written}; this is jdpim {__version__}: check its results against the "
            "changelog",
            PersistenceWarning,
            stacklevel=2,
        )
    classes = _classes()
    try:
        result = _decode(doc["result"], arrays, classes, written)
        parts = {k: _decode(doc[k], arrays, classes, written) for k in ("scene", "method")} if metadata else {}
    except (KeyError, TypeError, AttributeError) as e:  # a document jdpim's save did not write
        raise ValueError(f"{name}: malformed jdpim document ({type(e).__name__}: {e})") from None
    if not metadata:
        return result
    lost = [k for k in parts if parts[k] is None and doc[f"{k}_text"] is not None]
    if lost:
        warnings.warn(
            f"{name}: the {' and the '.join(lost)} {'is' if len(lost) == 1 else 'are'} not restored (None): saved "
            f"with a Python function, a device or a user class; Metadata.{lost[0]}_text describes "
            f"{'it' if len(lost) == 1 else 'them'}",
            PersistenceWarning,
            stacklevel=2,
        )
    meta = Metadata(
        doc["type"], parts["scene"], parts["method"], doc["scene_text"], doc["method_text"], doc["versions"],
        doc["created"], doc["format"],
    )  # fmt: skip
    return result, meta


class Persistent:
    """``save`` for every result class."""

    def save(self, path, *, scene=None, method=None) -> None:
        """Write this result to ``path`` (``.npz``) with the ``scene`` and ``method`` it came from as metadata;
        ``jdpim.load(path)`` reads it back exactly (see ``docs/persistence.md``)."""
        save(self, path, scene=scene, method=method)


class Labelled(Persistent):
    """``save`` and ``to_xarray``: results whose arrays have named axes (all but ``Sensitivity``: no grid)."""

    def to_xarray(self):
        """This result as an ``xarray.Dataset`` of named dimensions and coordinates (``pip install jdpim[xarray]``)."""
        return to_xarray(self)


def to_xarray(obj):
    """``obj`` as an ``xarray.Dataset``: dimensions ``path``, ``time``, ``coordinate``, ``x``, ``v``, ``level``,
    ``speed`` as they apply, the settings as attributes."""
    try:
        import xarray as xr
    except ImportError:
        raise ImportError("to_xarray needs xarray: pip install jdpim[xarray]") from None

    kind = type(obj).__name__
    times = np.asarray(obj.times, float)
    attrs = {"method": obj.method, "jdpim_version": __version__}
    if kind == "Result":
        data = {"states": (("path", "time", "coordinate"), obj.states), "weights": ("path", obj.weights)}
        coords = {"time": times, "coordinate": list(obj.coordinates)}
        bounds = obj.barrier if isinstance(obj.barrier, dict) else {"": obj.barrier}
        attrs |= {f"barrier_{k}".rstrip("_"): float(b) for k, b in bounds.items() if b is not None}
    elif kind == "GridResult":
        data = {
            "density": (("time", "x", "v"), obj.density),
            "x_weights": ("x", obj.x_weights),
            "v_weights": ("v", obj.v_weights),
            "mass_defect": ("time", obj.mass_defect),
            "edge_mass": ("time", obj.edge_mass),
        }
        data |= {k: ((), getattr(obj, k)) for k in ("residual", "step_gain", "newton_steps", "virial")}
        coords = {"time": times, "x": np.asarray(obj.x), "v": np.asarray(obj.v)}
        attrs |= {k: int(getattr(obj, k)) for k in ("order", "folded", "stationary", "has_barrier")}
    elif kind == "FirstPassage":
        tl = ("time", "level")
        data = {k: (tl, getattr(obj, k)) for k in ("probability", "probability_stderr", "lost_mass", "grid_error")}
        for key in ("derivative", "derivative_stderr"):
            data |= {f"{key}_{n}": (tl, d) for n, d in (getattr(obj, key) or {}).items()}
        coords = {"time": times, "level": np.asarray(obj.levels)}
        attrs |= {k: getattr(obj, k) for k in ("n_evaluations", "n_replicates")}
    elif kind == "ImpactStatistics":
        data = {k: ("time", getattr(obj, k)) for k in ("probability", "probability_stderr", "mean_count")}
        data |= {"mean_count_stderr": ("time", obj.mean_count_stderr)}
        coords = {"time": times}
        if obj.speed_edges is not None:
            edges = np.asarray(obj.speed_edges)
            data |= {"speed_density": (("time", "speed"), obj.speed_density), "speed_edges": ("edge", edges)}
            coords |= {"speed": 0.5 * (edges[1:] + edges[:-1])}
    elif kind == "Tracked":
        data = {"values": (("path", "time", "component"), obj.values), "weights": ("path", obj.weights)}
        data |= {k: (("time", "component"), getattr(obj, k)) for k in ("mean", "mean_stderr")}
        coords = {"time": times}
    else:
        raise TypeError(f"to_xarray takes a jdpim result, got {kind}")
    data = {k: (dims, np.asarray(v)) for k, (dims, v) in data.items() if v is not None}
    attrs = {k: v for k, v in attrs.items() if v is not None}
    return xr.Dataset(data, coords=coords, attrs=attrs)
