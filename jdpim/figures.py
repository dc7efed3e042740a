"""Figures for print: symbols in mathtext, dimensionless axes cut to where the mass is, round contour levels.

The helpers that ``jdpim run``, scene files, ``jdpim paper`` and the notebooks draw with:
``pyplot()``, ``marginal(ax, grid, curves, var)``, ``joint(fig, axes, x, v, panels)``, ``scene_title(...)``,
``symbol(var)`` and ``mass_range(samples, weights)``.

DPIM is drawn as a line, Monte Carlo as dots, references as thin dashed lines; a standard error, when
given, is a band of plus or minus two standard errors around the curve (or error bars on the dots).
"""

from __future__ import annotations

import math
import re

import numpy as np

LABEL = {"x": r"$x$", "v": r"$x'$"}  # one degree of freedom; other coordinates: see symbol()
UNIT = "(dimensionless)"
STYLE = {
    "dpim": {"color": "C3", "ls": "-", "lw": 1.4},
    "monte_carlo": {"color": "k", "ls": "none", "marker": "o", "ms": 2.6},
    "reference": {"color": "C0", "ls": "--", "lw": 1.0},
}
NAME = {"dpim": "DPIM", "monte_carlo": "MCS"}


def pyplot():
    """``matplotlib.pyplot`` on the non-interactive Agg backend, with print-friendly defaults."""
    import matplotlib

    if matplotlib.get_backend().lower() not in ("agg", "module://matplotlib_inline.backend_inline"):
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": 9, "axes.titlesize": 9, "legend.fontsize": 7.5, "mathtext.fontset": "cm"})
    return plt


def symbol(var: str) -> str:
    """A coordinate's axis symbol in mathtext: ``"x"`` -> ``$x$``, ``"v"`` -> ``$x'$``, ``"x1"`` -> ``$x_{1}$``,
    any other name upright (``"damper_x"`` -> ``$\\mathrm{damper\\_x}$``)."""
    if var in LABEL:
        return LABEL[var]
    if m := re.fullmatch(r"([A-Za-z]+)_?(\d+)", var):
        return f"${m[1]}_{{{m[2]}}}$"
    return r"$\mathrm{" + var.replace("_", r"\_") + "}$"


def scene_title(alpha, gamma, r, D) -> str:
    """``alpha = gamma = 0.03, r = 0.98, D = 0.03`` in mathtext (absent terms are left out)."""
    parts = []
    if alpha is not None and gamma is not None and float(alpha) == float(gamma):
        parts.append(rf"$\alpha = \gamma = {float(alpha):g}$")
    else:
        parts += [rf"${s} = {float(v):g}$" for s, v in ((r"\alpha", alpha), (r"\gamma", gamma)) if v is not None]
    parts.append(rf"$r = {float(r):g}$")
    if D is not None:
        parts.append(rf"$D = {float(D):g}$")
    return ", ".join(parts)


def mass_range(samples, weights, *, q: float = 0.999, lower=None, upper=None) -> tuple[float, float]:
    """The interval holding the central ``q`` of the weighted samples (from ``lower`` and to ``upper``, the
    bounds of the quantity, where given).

    Axes cut there show where the probability is. Non-finite samples are ignored.
    """
    y, w = np.asarray(samples, float).ravel(), np.asarray(weights, float).ravel()
    ok = np.isfinite(y)
    y, w = y[ok], w[ok]
    order = np.argsort(y)
    y, cw = y[order], np.cumsum(w[order]) / np.sum(w)
    if lower is not None and upper is not None:
        return float(lower), float(upper)
    if lower is not None:
        return float(lower), float(np.interp(q, cw, y))
    if upper is not None:
        return float(np.interp(1 - q, cw, y)), float(upper)
    tail = (1 - q) / 2
    return float(np.interp(tail, cw, y)), float(np.interp(1 - tail, cw, y))


def nice_step(span: float, n: int = 8) -> float:
    """A round step (1, 2, 2.5 or 5 times a power of ten) that cuts ``span`` into about ``n`` parts."""
    raw = span / n
    base = 10 ** math.floor(math.log10(raw))
    return next(m * base for m in (1, 2, 2.5, 5, 10) if m * base >= raw)


def contour_levels(p_max: float, *, n: int = 8, tail: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Round contour levels for a density with peak ``p_max``: ``(levels, ticks)``.

    The lowest levels are round values near ``tail * p_max`` and ``5 tail * p_max`` (so the tails are
    drawn), the others multiples of a round step; ``ticks`` are all of them (for the colour bar).
    """
    step = nice_step(p_max, n)
    multiples = np.arange(1, math.floor(p_max / step) + 1) * step
    low = [nice_step(f * p_max * 8, 8) for f in (tail, 5 * tail)]  # round numbers of the order of f * p_max
    levels = np.unique(np.concatenate([[v for v in low if v < step], multiples]))
    return levels, levels


def marginal(ax, grid, curves, var: str, *, n_dots: int = 40):
    """Draw marginal PDFs on ``ax``.

    ``curves``: ``(kind, label, p, se)`` with ``kind`` in ``STYLE`` (``"dpim"`` line, ``"monte_carlo"``
    dots, ``"reference"`` dashed) and ``se`` a standard error (band or bars of two ``se``) or ``None``.
    """
    grid = np.asarray(grid)
    every = max(1, len(grid) // n_dots)
    for kind, label, p, se in curves:
        p = np.asarray(p)
        style = STYLE[kind]
        if kind == "monte_carlo":
            g, pp = grid[::every], p[::every]
            if se is not None:
                ax.errorbar(g, pp, yerr=2 * np.asarray(se)[::every], fmt="none", ecolor="0.55", elinewidth=0.7)
            ax.plot(g, pp, label=label, **style)
        else:
            ax.plot(grid, p, label=label, **style)
            if se is not None:
                se = np.asarray(se)
                ax.fill_between(grid, p - 2 * se, p + 2 * se, color=style["color"], alpha=0.2, lw=0)
    ax.set_xlim(grid[0], grid[-1])
    ax.set_ylim(bottom=0)
    ax.set_xlabel(f"{symbol(var)} {UNIT}")
    ax.set_ylabel(f"$p$({symbol(var)})")


def joint(fig, axes, x_grid, v_grid, panels, *, vars=("x", "v"), cmap: str = "viridis"):
    """Filled contours of joint PDFs ``panels = [(title, p[len(x_grid), len(v_grid)]), ...]`` on ``axes``.

    ``vars``: the coordinates on the horizontal and vertical axes (names, as for :func:`symbol`). Shared round
    levels (lowest near 1 % of the peak), one colour bar with round ticks.
    """
    p_max = max(float(np.max(p)) for _, p in panels)
    levels, ticks = contour_levels(p_max)
    levels = np.append(levels, max(p_max, levels[-1]) * 1.0001) if levels[-1] < p_max else levels
    cs = None
    for ax, (title, p) in zip(axes, panels, strict=True):
        cs = ax.contourf(x_grid, v_grid, np.asarray(p).T, levels=levels, cmap=cmap)
        ax.set_title(title)
        ax.set_xlabel(f"{symbol(vars[0])} {UNIT}")
    axes[0].set_ylabel(f"{symbol(vars[1])} {UNIT}")
    bar = fig.colorbar(cs, ax=list(axes), shrink=0.9, ticks=ticks)
    bar.set_label(f"$p({symbol(vars[0]).strip('$')}, {symbol(vars[1]).strip('$')})$")
    return levels
