"""Sensitivities of response PDFs: ``sensitivity`` and its per-parameter estimators."""

from ._estimators import CentralDifference as CentralDifference
from ._estimators import LikelihoodRatio as LikelihoodRatio
from ._estimators import NoiseScaling as NoiseScaling
from ._estimators import Pathwise as Pathwise
from ._sensitivity import Sensitivity as Sensitivity
from ._sensitivity import sensitivity as sensitivity
