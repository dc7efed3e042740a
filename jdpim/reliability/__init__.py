"""Failure probabilities: the probability that a response quantity has exceeded a level in [0, t]."""

from ._first_passage import FirstPassage as FirstPassage
from ._first_passage import first_passage as first_passage
from ._subset import SubsetSimulation as SubsetSimulation
