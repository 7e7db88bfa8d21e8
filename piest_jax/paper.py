"""The paper's simulation study: Figs. 5 and 6 of Xu, Zhou & Tan (2021), and the batch study of
the final estimate's bias and spread under measurement noise.

`piest reproduce` runs [`reproduce`][] and [`figure`][] and writes [`public_report`][].
"""

from ._estimation.batch import noise_figure as noise_figure
from ._estimation.batch import noise_study as noise_study
from ._estimation.reproduce import CASES as CASES
from ._estimation.reproduce import DEFAULT_P0 as DEFAULT_P0
from ._estimation.reproduce import DT as DT
from ._estimation.reproduce import DURATION as DURATION
from ._estimation.reproduce import FIGURES as FIGURES
from ._estimation.reproduce import THRESHOLDS as THRESHOLDS
from ._estimation.reproduce import PaperCase as PaperCase
from ._estimation.reproduce import figure as figure
from ._estimation.reproduce import public_report as public_report
from ._estimation.reproduce import reproduce as reproduce
from ._estimation.reproduce import time_to_tolerance as time_to_tolerance

__all__ = [
    "CASES",
    "DEFAULT_P0",
    "DT",
    "DURATION",
    "FIGURES",
    "THRESHOLDS",
    "PaperCase",
    "figure",
    "noise_figure",
    "noise_study",
    "public_report",
    "reproduce",
    "time_to_tolerance",
]
