"""jdpim: response PDFs of randomly excited vibro-impact oscillators by the Direct Probability
Integral Method (DPIM), with Monte Carlo simulation and exact solutions beside it, in JAX."""

import importlib.metadata as _metadata

from . import exact as exact
from . import figures as figures
from . import metrics as metrics
from ._cpu import use_cpu_cores as use_cpu_cores
from ._density import RULES as RULES
from ._density import bandwidth as bandwidth
from ._density import histogram as histogram
from ._density import kde as kde
from ._density import kde_2d as kde_2d
from ._density import kde_stderr as kde_stderr
from ._distributions import Normal as Normal
from ._distributions import Uniform as Uniform
from ._estimators import CentralDifference as CentralDifference
from ._estimators import LikelihoodRatio as LikelihoodRatio
from ._estimators import NoiseScaling as NoiseScaling
from ._estimators import Pathwise as Pathwise
from ._estimators import SensitivityWarning as SensitivityWarning
from ._excitation import SpectralRepresentation as SpectralRepresentation
from ._grid_result import GridResult as GridResult
from ._integrate import ImpactRule as ImpactRule
from ._integrate import Substeps as Substeps
from ._models import AbstractOscillator as AbstractOscillator
from ._models import Oscillator as Oscillator
from ._models import VibroImpactOscillator as VibroImpactOscillator
from ._noise import WhiteNoise as WhiteNoise
from ._path_integration import PathIntegration as PathIntegration
from ._path_integration import PathIntegrationWarning as PathIntegrationWarning
from ._path_integration import path_integration as path_integration
from ._pipelines import NonFiniteWarning as NonFiniteWarning
from ._pipelines import dpim as dpim
from ._pipelines import dpim_points as dpim_points
from ._pipelines import monte_carlo as monte_carlo
from ._pipelines import simulate as simulate
from ._points import PointSet as PointSet
from ._points import gf_discrepancy as gf_discrepancy
from ._points import select_points as select_points
from ._replicates import dpim_replicates as dpim_replicates
from ._replicates import randomised_points as randomised_points
from ._result import Result as Result
from ._scene import Scene as Scene
from ._sensitivity import Sensitivity as Sensitivity
from ._sensitivity import parameter_names as parameter_names
from ._sensitivity import sensitivity as sensitivity
from ._sensitivity import with_parameters as with_parameters
from ._tuning import loo_log_likelihood as loo_log_likelihood
from ._tuning import refine_points as refine_points
from ._tuning import soft_voronoi_probabilities as soft_voronoi_probabilities
from ._tuning import tune_bandwidth as tune_bandwidth

try:
    __version__ = _metadata.version("jdpim")
except _metadata.PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0"
