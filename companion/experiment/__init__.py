"""The paper's experiment: synthetic participants, the grid of trials, reports (docs/experiment.md)."""
