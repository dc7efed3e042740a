"""Failure probabilities (first passage, subset simulation) and impact statistics."""

from ._first_passage import FirstPassage as FirstPassage
from ._first_passage import first_passage as first_passage
from ._fragility import Fragility as Fragility
from ._fragility import FragilityWarning as FragilityWarning
from ._fragility import fragility as fragility
from ._fragility import wilson_interval as wilson_interval
from ._impacts import ImpactStatistics as ImpactStatistics
from ._impacts import impact_statistics as impact_statistics
from ._peak import PeakDistribution as PeakDistribution
from ._peak import peak_distribution as peak_distribution
from ._subset import SubsetSimulation as SubsetSimulation
