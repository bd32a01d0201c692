"""CoL+ is CoL's schedule with the learner switches the ablation supported, set by the condition
(companion/learning/col_plus.py), wherever a condition is flown: fly, console, study, grid."""

from __future__ import annotations

import pytest

from companion.app import CONDITIONS, PERSON_CONDITIONS, condition_config, phases_for
from companion.config import CompanionConfig
from companion.errors import ConfigError
from companion.experiment.grid import TRAIN_CONDITIONS, ExperimentConfig, expand
from companion.experiment.report import COMPARISONS, LABELS
from companion.learning.col_plus import COL_PLUS, COL_PLUS_LEARNER, col_plus_config


def test_col_plus_sets_its_switches_over_the_configs_own_and_keeps_the_rest() -> None:
    cfg = CompanionConfig()
    own = cfg.model_copy(update={"learner": cfg.learner.model_copy(update={"demo_noise_std": 0.05, "hidden": (32, 32)})})
    plus = col_plus_config(own)
    assert {k: getattr(plus.learner, k) for k in COL_PLUS_LEARNER} == dict(COL_PLUS_LEARNER)
    assert plus.learner.hidden == (32, 32) and plus.session == own.session  # everything else as given
    assert own.learner.demo_noise_std == 0.05  # the given config is not changed


def test_only_the_col_plus_condition_trains_with_them() -> None:
    cfg = CompanionConfig()
    assert condition_config(cfg, COL_PLUS).learner.demo_noise_std == COL_PLUS_LEARNER["demo_noise_std"]
    for condition in ("demo", "int", "col", "eval"):
        assert condition_config(cfg, condition) == cfg
    assert phases_for(COL_PLUS, 8) == phases_for("col", 8)  # CoL's schedule


def test_col_plus_is_a_condition_of_every_place_a_condition_is_chosen() -> None:
    assert COL_PLUS in CONDITIONS and COL_PLUS in PERSON_CONDITIONS and COL_PLUS in TRAIN_CONDITIONS
    grid = ExperimentConfig(participants=("P1",), conditions=("col", COL_PLUS), interactions=(8,), seeds=(0,))
    assert sorted(t.key for t in expand(grid)) == ["P1-col-08-s0", "P1-colplus-08-s0"]
    assert LABELS[COL_PLUS] == "CoL+" and (COL_PLUS, "col") in COMPARISONS


def test_an_unknown_condition_is_still_refused() -> None:
    with pytest.raises(ConfigError, match="unknown condition"):
        phases_for("colplusplus", 4)
