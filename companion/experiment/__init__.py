"""The paper's experiment: synthetic participants, the grid of trials, the runner, results,
statistics and the report (docs/experiment.md)."""
