"""What other ddgjax packages need from `ddgjax.pointcloud` that users should not call (the host kNN graph, the
points' check, frames oriented by sign propagation along a spanning tree).

As `lineax.internal`: plain re-exports, visible to import graphs and type checkers (DESIGN.md, layout).
"""

from ._transport import forest_parents as forest_parents
from ._transport import oriented_frames as oriented_frames
from ._triangulation import check_neighbors as check_neighbors
from ._triangulation import check_points as check_points
from ._triangulation import nearest_neighbor_graph as nearest_neighbor_graph
