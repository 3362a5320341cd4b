"""Figures: static matplotlib drawings of curves, flows and mesh functions, and the interactive 3D viewer `show`.

The matplotlib functions draw on an `Axes` the caller made (`plt.subplots()` in a notebook, or
`matplotlib.figure.Figure().add_subplot()` in a script, as `ddgjax flow` does), and change no
global state (no pyplot, no backend). `import ddgjax` does not import this package or matplotlib,
and `import ddgjax.plot` does not import plotly (only `show` does).

    import matplotlib.pyplot as plt
    import ddgjax.curves as dc
    from ddgjax.plot import plot_flow

    result = dc.curve_shortening_flow(dc.flower(64), kind="B", tau=1e-3, steps=2000, save_every=100)
    fig, ax = plt.subplots()
    plot_flow(ax, result, color="tab:orange")

A function on a mesh is drawn by `plot_mesh_function(ax, mesh, values)`: an orthographic view,
faces painted back to front (no 3-D axes needed), returning the collection for `fig.colorbar`;
`plot_direction_field(ax, mesh, vectors)` draws tangent directions on top, in the same view.

`show(mesh, values, vectors=...)` returns an interactive plotly figure to turn with the mouse
(the `viewer` extra: `pip install "ddgjax[viewer]"`): in a notebook, in a browser (`fig.show()`),
or saved as a self-contained page (`fig.write_html(path)`).
"""

from ._matplotlib import plot_curve as plot_curve
from ._matplotlib import plot_direction_field as plot_direction_field
from ._matplotlib import plot_flow as plot_flow
from ._matplotlib import plot_mesh_function as plot_mesh_function
from ._matplotlib import polyline as polyline
from ._matplotlib import snapshot_indices as snapshot_indices
from ._view import OBLIQUE_VIEW as OBLIQUE_VIEW
from ._view import TOP_VIEW as TOP_VIEW
from ._view import is_flat as is_flat
from ._view import view_rotation as view_rotation
from ._viewer import show as show
