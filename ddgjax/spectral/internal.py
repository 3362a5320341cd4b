"""What other ddgjax packages need from `ddgjax.spectral` that users should not call (the wave kernel's energies and weights).

As `lineax.internal`: plain re-exports, visible to import graphs and type checkers (DESIGN.md, layout).
"""

from ._laplacian import wave_kernel_energies as wave_kernel_energies
from ._laplacian import wave_kernel_weights as wave_kernel_weights
