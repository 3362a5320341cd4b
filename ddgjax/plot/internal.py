"""What other ddgjax packages need from `ddgjax.plot` that users should not call (the rotations that put a chosen axis up).

As `lineax.internal`: plain re-exports, visible to import graphs and type checkers (DESIGN.md, layout).
"""

from ._view import UP_ROTATIONS as UP_ROTATIONS
