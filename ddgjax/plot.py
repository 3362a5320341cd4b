"""Drawing curves and curve-shortening flows with matplotlib.

Every function draws on a matplotlib `Axes` the caller made (`plt.subplots()` in a notebook, or
`matplotlib.figure.Figure().add_subplot()` in a script, as `ddgjax flow` does), and changes no
global state (no pyplot, no backend). `import ddgjax` does not import this module or matplotlib.

    import matplotlib.pyplot as plt
    import ddgjax.curves as dc
    from ddgjax.plot import plot_flow

    result = dc.curve_shortening_flow(dc.flower(64), kind="B", tau=1e-3, steps=2000, save_every=100)
    fig, ax = plt.subplots()
    plot_flow(ax, result, color="tab:orange")
"""

from __future__ import annotations

import numpy as np
from jaxtyping import ArrayLike
from matplotlib.colors import to_rgb

from .curves import Curve, CurveFlowResult
from .curves._curve import require_curve


def polyline(points: ArrayLike, closed: bool = True) -> np.ndarray:
    """The `(n, 2)` points as a NumPy array to draw, with the first repeated at the end when `closed`."""
    points = np.asarray(points)
    return np.vstack([points, points[:1]]) if closed else points


def plot_curve(axes, curve: Curve, **style) -> list:
    """Draw `curve` as a polygon (with its closing edge when closed); `style` goes to `axes.plot`.

    Returns the matplotlib lines.
    """
    curve = require_curve("curve", curve)
    return axes.plot(*polyline(curve.points, curve.closed).T, **style)


def snapshot_indices(result: CurveFlowResult, snapshots: int) -> np.ndarray:
    """Indices of `snapshots` saved states of `result` spread evenly from the first to the last."""
    return np.unique(np.linspace(0, result.points.shape[0] - 1, snapshots).round().astype(int))


def plot_flow(axes, result: CurveFlowResult, *, snapshots: int = 6, color="tab:blue") -> np.ndarray:
    """Overlay snapshots of a curve-shortening flow and the path of its vertex centroid.

    The initial curve is drawn black and dashed; later snapshots in `color`, lighter early and full
    colour (thicker, with its vertices as dots) at the end; the centroid's path runs from `+` to `x`.
    The axes get an equal aspect ratio. Returns the indices of the saved states drawn
    (`snapshot_indices(result, snapshots)`).
    """
    points = np.asarray(result.points)
    chosen = snapshot_indices(result, snapshots)
    base = np.array(to_rgb(color))
    axes.plot(*polyline(points[0], result.closed).T, color="black", lw=1.2, ls="--")
    later = chosen[1:]
    for order, index in enumerate(later, start=1):
        shade = 0.25 + 0.75 * order / len(later)
        axes.plot(*polyline(points[index], result.closed).T, color=1 - shade * (1 - base), lw=1.0 + (index == chosen[-1]))
    axes.plot(*points[chosen[-1]].T, "o", color=base, ms=2.5)
    centroid = np.asarray(result.centroid)
    axes.plot(*centroid.T, color="black", lw=1)
    axes.plot(*centroid[0], "k+", ms=9)
    axes.plot(*centroid[-1], "kx", ms=7)
    axes.set_aspect("equal")
    return chosen
