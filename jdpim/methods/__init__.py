"""Methods: DPIM, Monte Carlo and path integration, each a settings object that ``solve(scene, method)`` runs."""

from ._base import AbstractMethod as AbstractMethod
from ._base import solve as solve
from ._dpim import DPIM as DPIM
from ._monte_carlo import MonteCarlo as MonteCarlo
from ._path_integration import PathIntegration as PathIntegration
