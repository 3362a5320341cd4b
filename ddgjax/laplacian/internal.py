"""What other ddgjax packages need from `ddgjax.laplacian` that users should not call (storage plans of vertex-vertex operators, the robust (intrinsic Delaunay) choice, the tufted cover and its flips).

As `lineax.internal`: plain re-exports, visible to import graphs and type checkers (DESIGN.md, layout).
"""

from ._cotan import apply_slot_weights as apply_slot_weights
from ._cotan import dirichlet_energy_length_weights as dirichlet_energy_length_weights
from ._intrinsic import replayed_lengths_sq as replayed_lengths_sq
from ._operators import resolve_robust as resolve_robust
from ._plan import dec_plan as dec_plan
from ._plan import edge_slot_maps as edge_slot_maps
from ._plan import vertex_plan as vertex_plan
from ._tufted import tufted_delaunay as tufted_delaunay
