"""CoL+: the paper's Cycle-of-Learning with the learner switches the ablation supported.

The ``colplus`` condition is CoL's schedule (half demonstrations, then interventions) with these
learner settings on (docs/learner.md, "Learner switches"); everything else is CoL's. Which
switches, and their values, were fixed by the learner ablation (results/learner-ablation/) and
preregistered in docs/experiment.md ("CoL+") before the CoL+ grid: they are not a user's
tuning knob, so a config's own values of these keys are replaced for this condition (the other
conditions keep them).
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

from companion.config import CompanionConfig

COL_PLUS = "colplus"
"""The condition's name."""
COL_PLUS_LEARNER: Mapping[str, object] = MappingProxyType({
    "demo_noise_std": 0.2,  # DART: supported by the ablation's first round (+7.83 points [+0.88, +15.83])
})
"""The ``[companion.learner]`` settings CoL+ trains with (module docstring): the switches the
ablation has supported, at the values it tried; its second round (the mirror and the weighting
again, results/learner-ablation/PLAN.md amendment 2) may add to them before the preregistration."""


def col_plus_config(cfg: CompanionConfig) -> CompanionConfig:
    """``cfg`` with CoL+'s learner settings in place of its own (validated as a config file's)."""
    learner = type(cfg.learner).model_validate({**cfg.learner.model_dump(), **COL_PLUS_LEARNER})
    return cfg.model_copy(update={"learner": learner})
