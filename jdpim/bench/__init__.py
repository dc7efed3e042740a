"""Benchmarks: what accuracy costs in time.

Protocol for every timing: the program is compiled ahead of time (compile time reported separately),
run once as a warm-up, then run ``repeats`` times; the median wall time is reported.
"""

from .timing import Timing as Timing
from .timing import timed as timed
