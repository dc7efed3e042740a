"""Reports shared by ``jdpim run`` (the main job and scene files) and ``jdpim paper``.

Solving a scene with several methods (``jdpim.solve``, timed), the densities of the results on common grids,
the timing tables (Markdown, CSV), the versions, and the figures (``jdpim.figures``). Density arrays are keyed
as in a scene file's ``.npz``: ``<name>_pdf_<var>``, ``<name>_stderr_<var>``, ``<name>_joint`` (of ``x`` and
``v``) or ``<name>_joint_<a>_<b>``, with the names ``"dpim"``, ``"monte_carlo"`` and ``"reference"``; ``var``
is any coordinate of the model (``"x"``, ``"v"``; ``"x1"``, ``"v2"``, ... for several degrees of freedom).
"""

from __future__ import annotations

import csv
import json
import pathlib
import re
import time

import numpy as np

from . import figures, metrics
from ._io import versions as versions  # the metadata of every output, saved results' too

NAME = {**figures.NAME, "reference": "path integration"}  # legends and panel titles


def logger(quiet: bool):
    """The progress log: ``print`` (flushed), or nothing with ``--quiet``."""
    return (lambda s: None) if quiet else (lambda s: print(s, flush=True))


def timed(fn, log, what: str):
    """``fn()`` until its arrays are ready, logged as ``what``; returns ``(value, wall_s, cpu_s)``.

    The times are of the whole call, compilation included where it compiles (the first run of a shape).
    """
    import jax

    log(f"{what} ...")
    t0, c0 = time.perf_counter(), time.process_time()
    value = jax.block_until_ready(fn())
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    log(f"{what}: {wall:.1f} s wall, {cpu:.1f} s CPU")
    return value, wall, cpu


def solve_timed(scene, method, log, what: str):
    """``jdpim.solve(scene, method)`` under :func:`timed`; returns ``(result, wall_s, cpu_s)``."""
    import jdpim

    return timed(lambda: jdpim.solve(scene, method), log, what)


def timed_protocol(scene, method, *, repeats: int, warmup: bool = True):
    """A ``jdpim.DPIM`` or ``jdpim.MonteCarlo`` run under ``jdpim.bench.timed``'s protocol: ``(result, Timing)``.

    The ahead-of-time compilation is timed apart from the runs, the warm-up run (``warmup``) is not timed,
    and ``repeats`` runs give the median; the paths are split over ``method.devices`` (default: every local
    device), as ``jdpim.solve`` splits them.
    """
    import jax

    import jdpim
    from jdpim.bench import timed as bench_timed

    dpim = isinstance(method, jdpim.DPIM)
    return bench_timed(
        method.name,
        scene,
        method.n_points if dpim else method.n_samples,
        seed=0 if dpim else method.seed,
        points=method.points if dpim else None,
        chunk_size=method.chunk_size,
        repeats=repeats,
        warmup=warmup,
        devices=method.devices or jax.local_devices(),
    )


def reference(scene, method, log, what: str = "path integration (reference)"):
    """Path integration of ``scene`` by ``method`` (a ``jdpim.PathIntegration``), or ``None`` where it cannot run.

    Transient path integration needs saved times at or after its start ``t0``, on its step ``tau``
    (docs/path_integration.md); where ``scene`` has others, the log says why there is no reference.
    """
    try:
        return solve_timed(scene, method, log, what)[0]
    except ValueError as err:
        log(f"no path-integration reference: {err}")
        return None


def lower_bounds(model) -> dict:
    """``{coordinate: lower bound}`` of the coordinates a barrier or a constraint bounds from below."""
    bounds = model.bounds()
    if bounds is None:
        return {}
    if not isinstance(bounds, dict):  # one degree of freedom: the barrier of x
        bounds = {model.coordinates[0]: bounds}
    return {name: float(b) for name, b in bounds.items()}


def quantity_bounds(model, results, var) -> tuple:
    """``(lower, upper)`` of ``var`` (a coordinate or a function of the state) as floats, ``None`` for a side
    without a bound: the first sampling result's ``bounds(var)`` (from the model's constraints), else the
    coordinate's lower bound (``lower_bounds``)."""
    for res in results:
        if hasattr(res, "bounds"):
            return tuple(None if b is None else float(b) for b in res.bounds(var))
    return (lower_bounds(model).get(var) if isinstance(var, str) else None), None


def grids(scene, results, n_grid: int, names=None, q: float = 0.999) -> dict:
    """Grids of the coordinates ``names`` (default: every coordinate of the model), ``n_grid`` nodes each.

    Each covers the central ``q`` of the mass over every saved time and every sampling result
    (``jdpim.Result``) of ``results``. A coordinate bounded by a constraint (``x`` of a model with a barrier)
    starts or ends at its bound (:func:`quantity_bounds`); velocities (the second half of
    ``scene.model.coordinates``) are symmetric about 0. Returns ``{name: grid}`` in the order of ``names``.
    """
    coords = scene.model.coordinates
    out = {}
    for name in coords if names is None else names:
        i = coords.index(name)
        lower, upper = quantity_bounds(scene.model, results, name)
        ranges = []
        for res in results:
            y = np.asarray(res.states[..., i])
            w = np.broadcast_to(np.asarray(res.weights)[:, None], y.shape)
            ranges.append(figures.mass_range(y, w, q=q, lower=lower, upper=upper))
        if i >= len(coords) // 2:  # a velocity
            half = max(max(abs(a), abs(b)) for a, b in ranges)
            lo, hi = -half, half
        else:
            lo = lower if lower is not None else min(a for a, _ in ranges)
            hi = upper if upper is not None else max(b for _, b in ranges)
        out[name] = np.linspace(lo, hi, n_grid)
    return out


def quantity_grids(results, quantities: dict, times, n_grid: int, q: float = 0.999) -> dict:
    """Grids of functions of the state, ``{name: fn}`` (``fn``: state ``(n_state,)`` -> scalar), ``n_grid`` nodes
    each, covering the central ``q`` of the mass over the saved ``times`` and every sampling result of ``results``,
    from and to the bounds the model's constraints set (``Result.bounds``: a relative displacement spans its
    clearance)."""
    results = list(results)
    out = {}
    for name, fn in quantities.items():
        lower, upper = quantity_bounds(None, results, fn)
        ranges = []
        for res in results:
            y = np.stack([np.asarray(res.samples(fn, t)) for t in times])
            w = np.broadcast_to(np.asarray(res.weights)[None, :], y.shape)
            ranges.append(figures.mass_range(y, w, q=q, lower=lower, upper=upper))
        out[name] = np.linspace(min(a for a, _ in ranges), max(b for _, b in ranges), n_grid)
    return out


def _has_error(res) -> bool:
    """Whether ``res.pdf_error`` has an estimate: Monte Carlo, or path integration with ``estimate_error``."""
    return getattr(res, "independent", False) or getattr(res, "coarse", None) is not None


def _check_spread(res, var, times, name=None) -> None:
    """Fail in words where every finite path of a sampling result has one value of ``var`` (a coordinate, or a
    function of the state called ``name``) at a saved time: a point mass, for which the rule gives no kernel
    width (a mass not reached yet, a start at rest)."""
    name = var if name is None else name
    if not hasattr(res, "samples"):
        return
    for t in times:
        y = np.asarray(res.samples(var, t))
        y = y[np.isfinite(y)]
        if y.size and np.all(y == y[0]):
            raise ValueError(
                f"{name} has the value {y[0]:g} on every path of {res.method} at t = {t:g} s, a point mass without a "
                f"density; leave {name} out of the densities or save it later"
            )


def joint_name(pair) -> str:
    """The name of the joint density of a coordinate pair in keys and file names: ``"joint"`` for ``("x", "v")``
    (one degree of freedom, as before), else ``"joint_<a>_<b>"``."""
    return "joint" if tuple(pair) == ("x", "v") else f"joint_{pair[0]}_{pair[1]}"


def densities(results: dict, times, grids: dict, joints=None, joint_times=(), quantities=None) -> dict:
    """Densities of named results on common grids.

    Args:
        results: name -> ``jdpim.Result`` or ``jdpim.GridResult`` (a stationary one gives its density at
            every time).
        times: saved times of the marginals, s.
        grids: coordinate (``"x"``, ``"v"``, ``"x1"``, ...) or name of ``quantities`` -> 1-D grid of its marginal.
        joints: ``{(a, b): (grid_a, grid_b)}``, the coordinate pairs of the joint densities (``None``: none).
        joint_times: saved times of the joint densities, s.
        quantities: ``{name: fn}``, functions of the state (``(n_state,)`` -> scalar) named in ``grids``.

    Returns:
        ``<name>_pdf_<var>``, shape ``(len(times), len(grid))``; ``<name>_stderr_<var>`` of the same shape
        where the result has an error estimate (``pdf_error``); ``<name>_atoms_<var>``, shape ``(len(times), 2)``,
        the probability held at the lower and upper bound of a bounded ``var`` (``Result.atoms``; the density
        leaves it out); ``<name>_<joint_name(pair)>``, shape ``(len(joint_times), len(grid_a), len(grid_b))``,
        for each pair of ``joints``.
    """
    arrays = {}
    for name, res in results.items():
        at = [None] * len(times) if getattr(res, "stationary", False) else times  # a stationary density has no t
        joint_at = [None] * len(joint_times) if getattr(res, "stationary", False) else joint_times
        for key, g in grids.items():
            var = (quantities or {}).get(key, key)
            _check_spread(res, var, at, key)
            arrays[f"{name}_pdf_{key}"] = np.stack([np.asarray(res.pdf(var, g, t)) for t in at])
            if _has_error(res):
                arrays[f"{name}_stderr_{key}"] = np.stack([np.asarray(res.pdf_error(var, g, t)) for t in at])
            if hasattr(res, "atoms") and any(b is not None for b in res.bounds(var)):
                arrays[f"{name}_atoms_{key}"] = np.stack([np.asarray(res.atoms(var, t)) for t in at])
        for pair, pair_grids in (joints or {}).items():
            for var in pair:
                _check_spread(res, var, joint_at)
            arrays[f"{name}_{joint_name(pair)}"] = np.stack(
                [np.asarray(res.joint_pdf(pair, pair_grids, t)) for t in joint_at]
            )
    return arrays


def l1(arrays: dict, a: str, b: str, var: str, grid, i: int) -> float:
    """L1 distance between the marginals of ``var`` of results ``a`` and ``b`` in row ``i`` of :func:`densities`."""
    return metrics.l1(arrays[f"{a}_pdf_{var}"][i], arrays[f"{b}_pdf_{var}"][i], grid)


def markdown(rows: list[dict], columns) -> str:
    """A Markdown table of ``rows``: ``columns`` are ``(header, template, align)``, the template formatted with
    each row (``"{wall_s:.1f}"``), ``align`` ``"l"`` or ``"r"``."""
    lines = [
        "| " + " | ".join(h for h, _, _ in columns) + " |",
        "|" + "|".join("---" if a == "l" else "---:" for _, _, a in columns) + "|",
    ]
    lines += ["| " + " | ".join(tpl.format(**r) for _, tpl, _ in columns) + " |" for r in rows]
    return "\n".join(lines)


def probability_table(times, levels, probability, stderr=None, quantity: str = "q") -> str:
    """A Markdown table of first-passage probabilities ``(S, L)``: a row per saved time (s), a column per level,
    ``p ± se`` where ``stderr`` ``(S, L)`` is given, else ``p``. The bars of a magnitude (``|x|``) are escaped, so
    that they do not split the header's cells."""
    quantity = quantity.replace("|", r"\|")
    columns = [("t (s)", "{t:g}", "r")] + [(f"P({quantity} > {a:g})", f"{{p{j}}}", "r") for j, a in enumerate(levels)]
    p = np.asarray(probability)
    se = None if stderr is None else np.asarray(stderr)

    def cell(i, j):
        return f"{p[i, j]:.3g}" if se is None else f"{p[i, j]:.3g} ± {se[i, j]:.2g}"

    rows = [{"t": t, **{f"p{j}": cell(i, j) for j in range(len(levels))}} for i, t in enumerate(times)]
    return markdown(rows, columns)


def terminal(markdown_text: str) -> str:
    """Markdown text as the terminal shows it: the bars a table escapes (``P(\\|x1\\| > 0.5)``) unescaped."""
    return markdown_text.replace("\\|", "|")


def write_csv(path: pathlib.Path, rows: list[dict], comment: str) -> None:
    """``rows`` as CSV, after a ``# comment`` line (the settings they were measured with)."""
    with path.open("w", newline="") as fh:
        fh.write(f"# {comment}\n")
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def write_json(path: pathlib.Path, data: dict) -> None:
    """``data`` as indented JSON."""
    path.write_text(json.dumps(data, indent=2))


FILTER_NAME = re.compile(r"x[fh]\d*")  # the coordinates jdpim.filters appends: xf, xf1, xf2, ... and xh


def filter_coordinates(model) -> tuple[str, ...]:
    """The trailing coordinates of ``model`` that are filters (``jdpim.kanai_tajimi``, ``first_order_filter``,
    ``harmonic``): named as those functions name them and touched by no constraint."""
    names = model.coordinates[: model.dimension]
    touched = np.zeros(len(names), bool)
    for c in model.constraints:
        touched |= np.asarray(c.normal) != 0
    k = 0
    while k < len(names) - 1 and FILTER_NAME.fullmatch(names[-1 - k]) and not touched[-1 - k]:
        k += 1
    return names[len(names) - k :]


def scene_title(scene) -> str:
    """The scene's parameters for a figure title: ``figures.scene_title`` for one degree of freedom; for
    several the structure's degrees of freedom (filter coordinates named apart), the constraints' restitutions
    and ``D``."""
    import jdpim

    model, D = scene.model, np.asarray(scene.noise.D)
    if not isinstance(model, jdpim.MDOFOscillator):
        return figures.scene_title(model.alpha, model.gamma, model.r, scene.noise.D)
    filters = filter_coordinates(model)
    n = model.dimension - len(filters)
    parts = [f"{n} degree{'s' if n > 1 else ''} of freedom"]
    if filters:
        parts[0] += f" and {len(filters)} filter coordinate{'s' if len(filters) > 1 else ''} ({', '.join(filters)})"
    if model.constraints:
        rs = ", ".join(f"{float(c.r):g}" for c in model.constraints)
        j = len(model.constraints)
        parts.append(f"{j} constraint{'s' if j > 1 else ''} ($r$ = {rs})")
    parts.append(f"$D = {float(D):g}$" if D.ndim == 0 else f"$D$: {D.shape[0]} x {D.shape[1]} matrix")
    return ", ".join(parts)


def labels(results: dict) -> dict:
    """Legend labels of named results (``"MCS (10000 paths)"``), Monte Carlo first: its dots under the lines."""
    order = ("monte_carlo", "dpim", "reference")
    return {
        n: NAME[n] if n == "reference" else f"{NAME[n]} ({results[n].n_paths} paths)"
        for n in sorted(results, key=order.index)
    }


def curves(arrays: dict, labels: dict, var: str, i: int) -> list:
    """``figures.marginal``'s curves in row ``i`` of :func:`densities`: each result of ``labels`` (name ->
    legend label, drawn in the style of its name) with its error band where it has one; where a result holds
    probability at the bounds of ``var`` (``<name>_atoms_<var>``), its label gives those masses."""
    out = []
    for n, label in labels.items():
        se, atoms = arrays.get(f"{n}_stderr_{var}"), arrays.get(f"{n}_atoms_{var}")
        if atoms is not None and np.any(atoms[i] > 0):
            label = f"{label}; held at the bounds: {atoms[i][0]:.2g}, {atoms[i][1]:.2g}"
        out.append((n, label, arrays[f"{n}_pdf_{var}"][i], None if se is None else se[i]))
    return out


def marginal_figure(grids: dict, times, panel_curves, title: str, *, title_size=None):
    """Marginal PDFs: a row of panels per variable of ``grids``, a column per saved time (s).

    ``panel_curves(var, i)`` gives the ``figures.marginal`` curves of the panel of ``var`` at ``times[i]``.
    """
    plt = figures.pyplot()
    fig, axes = plt.subplots(len(grids), len(times), figsize=(3.2 * len(times), 0.2 + 2.6 * len(grids)), squeeze=False)
    for row, (var, g) in enumerate(grids.items()):
        for i, t in enumerate(times):
            figures.marginal(axes[row, i], g, panel_curves(var, i), var)
            axes[row, i].set_title(f"$t = {t:g}$ s")
    axes[0, -1].legend()
    fig.suptitle(title, **({} if title_size is None else {"fontsize": title_size}))
    fig.tight_layout()
    return fig


def joint_figure(x_grid, v_grid, panels, title: str, *, vars=("x", "v"), title_size=None):
    """Joint PDFs side by side on shared contour levels: ``panels = [(title, p[len(x_grid), len(v_grid)])]``;
    ``vars`` names the coordinates of the two grids."""
    plt = figures.pyplot()
    fig, axes = plt.subplots(
        1, len(panels), figsize=(3.5 * len(panels) + 0.8, 3.3), sharey=True, layout="constrained", squeeze=False
    )
    figures.joint(fig, axes[0], x_grid, v_grid, panels, vars=vars)
    fig.suptitle(title, **({} if title_size is None else {"fontsize": title_size}))
    return fig


def draw(scene, arrays: dict, grids: dict, labels: dict, out: pathlib.Path, *, prefix="", joints=None):
    """The figures of a run in ``out``; returns their file names.

    ``<prefix>marginal_<var>.png`` for each coordinate of ``grids`` (a panel per saved time) and
    ``<prefix><joint_name(pair)>.png`` for each pair of ``joints`` (``{(a, b): (grid_a, grid_b)}``; a panel
    per result, at the last saved time), from the :func:`densities` ``arrays`` of the results named in
    ``labels``.
    """
    title = scene_title(scene)
    names = []
    for var, g in grids.items():
        fig = marginal_figure({var: g}, scene.save_at, lambda var, i: curves(arrays, labels, var, i), title)
        names += save(fig, out, f"{prefix}marginal_{var}")
    t = scene.save_at[-1]
    for pair, (ga, gb) in (joints or {}).items():
        panels = [(f"{NAME[n]}, $t = {t:g}$ s", arrays[f"{n}_{joint_name(pair)}"][-1]) for n in labels]
        names += save(joint_figure(ga, gb, panels, title, vars=pair), out, f"{prefix}{joint_name(pair)}")
    return names


def save(fig, out: pathlib.Path, stem: str, *, pdf: bool = False) -> list[str]:
    """Write ``fig`` to ``out/<stem>.png`` (150 dpi) and, with ``pdf``, ``out/<stem>.pdf``; close it.

    Returns the file names written.
    """
    names = [f"{stem}.png"] + ([f"{stem}.pdf"] if pdf else [])
    for name in names:
        fig.savefig(out / name, dpi=150)
    figures.pyplot().close(fig)
    return names
