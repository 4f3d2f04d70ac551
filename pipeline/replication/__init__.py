"""Replication of the backlash paper's results ([BacklashNN], section 4 and 5) on one data set:
the numbers (``fitting``: the network's run, the ANOVA scores, the k-NN accuracy, the verdicts
given the other inputs, and the table beside the paper's) and their figures and written
report (``plotting``).
"""

from pipeline.replication.fitting import (
    DEVIATIONS,
    PAPER,
    PAPER_TABLE5,
    comparison_rows,
    network_run,
    replicate,
)
from pipeline.replication.plotting import FILES, markdown, plot_fig10, plot_fig13, write_replication

__all__ = ["DEVIATIONS", "FILES", "PAPER", "PAPER_TABLE5", "comparison_rows", "markdown",
           "network_run", "plot_fig10", "plot_fig13", "replicate", "write_replication"]
