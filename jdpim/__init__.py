"""jdpim: response PDFs of randomly excited vibro-impact oscillators by the Direct Probability
Integral Method (DPIM), with Monte Carlo simulation and exact solutions beside it, in JAX."""

from . import _io
from . import design as design
from . import exact as exact
from . import figures as figures
from . import filters as filters
from . import metrics as metrics
from . import reliability as reliability
from . import results as results
from . import statistics as statistics
from . import systems as systems
from . import tracking as tracking
from ._checkpoint import Checkpoint as Checkpoint
from ._cpu import use_cpu_cores as use_cpu_cores
from ._distributions import LogNormal as LogNormal
from ._distributions import Normal as Normal
from ._distributions import TruncatedNormal as TruncatedNormal
from ._distributions import Uniform as Uniform
from ._engine.settings import ImpactRule as ImpactRule
from ._engine.settings import Substeps as Substeps
from ._envelopes import Jennings as Jennings
from ._envelopes import ShinozukaSato as ShinozukaSato

# evolve: fully non-stationary noise (evolutionary spectra)
from ._evolutionary import AbstractEvolutionarySpectrum as AbstractEvolutionarySpectrum
from ._evolutionary import EvolutionaryKanaiTajimi as EvolutionaryKanaiTajimi
from ._evolutionary import EvolutionarySpectrum as EvolutionarySpectrum
from ._excitation import AbstractExcitation as AbstractExcitation
from ._excitation import AbstractNodes as AbstractNodes
from ._excitation import ArrayNodes as ArrayNodes
from ._excitation import GaussianNodes as GaussianNodes
from ._excitation import SpectralRepresentation as SpectralRepresentation
from ._io import PersistenceWarning as PersistenceWarning
from ._io import load as load
from ._mdof import Barrier as Barrier
from ._mdof import MDOFOscillator as MDOFOscillator
from ._models import AbstractOscillator as AbstractOscillator
from ._models import AbstractSystem as AbstractSystem
from ._models import Oscillator as Oscillator
from ._models import VibroImpactOscillator as VibroImpactOscillator
from ._noise import WhiteNoise as WhiteNoise
from ._points import PointSet as PointSet
from ._points import gf_discrepancy as gf_discrepancy
from ._points import select_points as select_points
from ._replicates import randomised_points as randomised_points
from ._scene import Scene as Scene
from ._scene import parameter_names as parameter_names
from ._scene import with_parameters as with_parameters
from ._tuning import loo_log_likelihood as loo_log_likelihood
from ._tuning import refine_points as refine_points
from ._tuning import soft_voronoi_probabilities as soft_voronoi_probabilities
from ._tuning import tune_bandwidth as tune_bandwidth
from ._version import __version__ as __version__
from ._warnings import StepSizeWarning as StepSizeWarning
from .filters import clough_penzien as clough_penzien
from .filters import first_order_filter as first_order_filter
from .filters import harmonic as harmonic
from .filters import kanai_tajimi as kanai_tajimi
from .methods._base import AbstractMethod as AbstractMethod
from .methods._base import solve as solve
from .methods._dpim import DPIM as DPIM
from .methods._dpim import dpim as dpim
from .methods._dpim import dpim_replicates as dpim_replicates
from .methods._monte_carlo import MonteCarlo as MonteCarlo
from .methods._monte_carlo import monte_carlo as monte_carlo
from .methods._path_integration import PathIntegration as PathIntegration
from .methods._path_integration import PathIntegrationWarning as PathIntegrationWarning
from .methods._path_integration import path_integration as path_integration
from .methods._paths import NonFiniteWarning as NonFiniteWarning
from .methods._paths import dpim_points as dpim_points
from .methods._paths import simulate as simulate
from .reliability import FirstPassage as FirstPassage
from .reliability import Fragility as Fragility
from .reliability import FragilityWarning as FragilityWarning
from .reliability import ImpactStatistics as ImpactStatistics
from .reliability import PeakDistribution as PeakDistribution
from .reliability import SubsetSimulation as SubsetSimulation
from .reliability import first_passage as first_passage
from .reliability import fragility as fragility
from .reliability import impact_statistics as impact_statistics
from .reliability import peak_distribution as peak_distribution
from .reliability._failure import AbstractFailureMethod as AbstractFailureMethod
from .results import Planes
from .results._density import RULES as RULES
from .results._density import bandwidth as bandwidth
from .results._density import histogram as histogram
from .results._density import kde as kde
from .results._density import kde_2d as kde_2d
from .results._density import kde_stderr as kde_stderr
from .results._grid import GridResult as GridResult
from .results._samples import Result as Result
from .sensitivities._estimators import CentralDifference as CentralDifference
from .sensitivities._estimators import LikelihoodRatio as LikelihoodRatio
from .sensitivities._estimators import NoiseScaling as NoiseScaling
from .sensitivities._estimators import Pathwise as Pathwise
from .sensitivities._estimators import SensitivityWarning as SensitivityWarning
from .sensitivities._sensitivity import Sensitivity as Sensitivity
from .sensitivities._sensitivity import sensitivity as sensitivity
from .statistics import ResponseAutocorrelation as ResponseAutocorrelation
from .statistics import ResponseMoments as ResponseMoments
from .statistics import ResponseSpectrum as ResponseSpectrum
from .statistics import response_autocorrelation as response_autocorrelation
from .statistics import response_moments as response_moments
from .statistics import response_psd as response_psd
from .systems import adjacent_buildings as adjacent_buildings
from .systems import gear_pair as gear_pair
from .systems import impact_damper as impact_damper
from .systems import pounding_frame as pounding_frame
from .tracking import AbstractTracked as AbstractTracked
from .tracking import Tracked as Tracked
from .tracking import track as track

_io.allow(
    Result, GridResult, FirstPassage, ImpactStatistics, Sensitivity,
    ResponseMoments, ResponseSpectrum, ResponseAutocorrelation, Fragility, Tracked, PeakDistribution,
    ShinozukaSato, Jennings,
    Scene, VibroImpactOscillator, Oscillator, MDOFOscillator, Barrier,
    WhiteNoise, SpectralRepresentation, GaussianNodes, ImpactRule, Substeps,
    Normal, Uniform, TruncatedNormal, LogNormal, PointSet, Planes,
    DPIM, MonteCarlo, PathIntegration, SubsetSimulation,
    Pathwise, LikelihoodRatio, NoiseScaling, CentralDifference,
)  # fmt: skip
_io.allow(EvolutionaryKanaiTajimi, EvolutionarySpectrum)  # evolve
