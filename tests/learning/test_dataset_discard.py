"""Discarding the last episode of the human dataset: out of training, never out of the file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from companion.learning.dataset import HumanDataset, discarded_episodes, load_csv
from companion.msg.sample import Sample, Source


def _sample(i: int, episode: int, source: Source = Source.DEMONSTRATION) -> Sample:
    obs = np.full(15, 0.5, np.float32)
    obs[0] = i
    return Sample(episode, i, i * 0.1, source, obs, np.array([0.0, 0.0, 0.0, 0.0]))


def test_the_last_episode_leaves_training_and_the_file_keeps_it_with_an_audit_line(tmp_path: Path) -> None:
    path = tmp_path / "human.csv"
    with HumanDataset(path) as ds:
        ds.extend(_sample(i, 0) for i in range(3))
        ds.extend(_sample(i, 1, Source.INTERVENTION) for i in range(3, 8))
        before = ds.view()
        with pytest.raises(ValueError, match="only the last one"):
            ds.discard_episode(0, "not the last")
        assert ds.discard_episode(1, "nobody on the sticks") == 5
        with pytest.raises(ValueError, match="already"):
            ds.discard_episode(1, "twice")
        assert len(ds) == 3 and ds.counts[Source.INTERVENTION] == 0
        ds.append(_sample(8, 2))  # appends after a discard never rewrite rows an old view holds
        np.testing.assert_array_equal(before.obs[:, 0], np.arange(8, dtype=np.float32))
        np.testing.assert_array_equal(ds.view().obs[:, 0], [0, 1, 2, 8])
    assert len(load_csv(path).episode) == 9  # nothing deleted from the file
    audit = [json.loads(line) for line in HumanDataset.discards_path(path).read_text().splitlines()]
    assert audit[0]["episode"] == 1 and audit[0]["rows"] == 5 and audit[0]["reason"] == "nobody on the sticks"
    assert discarded_episodes(path) == {1}
    with HumanDataset(path) as again:  # a resumed run trains without it too
        np.testing.assert_array_equal(again.view().obs[:, 0], [0, 1, 2, 8])
        assert again.last_episode == 2


def test_an_episode_without_samples_can_be_discarded_for_the_record(tmp_path: Path) -> None:
    with HumanDataset(tmp_path / "human.csv") as ds:
        ds.append(_sample(0, 0))
        assert ds.discard_episode(4, "policy flew it alone, stopped early") == 0
        assert len(ds) == 1
