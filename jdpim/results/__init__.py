"""Results: weighted paths (``Result``) and grid densities (``GridResult``), one interface (``AbstractResult``)."""

from ._base import AbstractResult as AbstractResult
from ._grid import GridResult as GridResult
from ._samples import Planes as Planes
from ._samples import Result as Result
