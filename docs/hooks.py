"""mkdocs hooks of the documentation site (mkdocs.yml: `hooks:`); not a page (`exclude_docs`).

The notebooks' kernels inherit this process's environment: `PLOTLY_RENDERER` makes `ddgjax.plot.show`'s figures
HTML that loads plotly.js from its CDN (plotly >= 6 otherwise writes only a mimetype nbconvert cannot render,
and `"notebook"` would embed ~5 MB of plotly.js in every page with a figure).
"""

import os

os.environ.setdefault("PLOTLY_RENDERER", "notebook_connected")
