"""Symmetry augmentation: the left/right mirror of observations and actions, and the learner's
minibatches with ``mirror_augment`` on and off."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.config import LearnerConfig
from companion.errors import ConfigError
from companion.learning.augment import Mirror, mirror_signs
from companion.learning.dataset import HumanDataset
from companion.learning.learner import Learner
from companion.msg.observation import OBS_NAMES, Observation
from companion.msg.pad import PadDetection
from companion.msg.sample import Sample, Source
from sitl.camera import CameraRenderer
from sitl.config import CameraConfig, WorldConfig
from sitl.world import World

# Written out here rather than taken from the module: what a left/right mirror does to each entry.
EXPECTED_OBS_SIGN = {
    "north_m": 1, "east_m": -1, "down_m": 1,
    "roll_rad": -1, "pitch_rad": 1, "yaw_rad": -1,
    "vn_m_s": 1, "ve_m_s": -1, "vd_m_s": 1,
    "p_rad_s": -1, "q_rad_s": 1, "r_rad_s": -1,
    "pad_u": -1, "pad_v": 1, "pad_radius": 1,
}
EXPECTED_ACTION_SIGN = (-1, 1, -1, 1)  # roll, pitch, yaw, throttle


def _observations(rng: np.random.Generator, n: int) -> np.ndarray:
    obs = rng.uniform(-2, 2, size=(n, len(OBS_NAMES))).astype(np.float32)
    yaw = OBS_NAMES.index("yaw_rad")
    obs[:, yaw] = rng.uniform(-1, 1, size=n).astype(np.float32)
    obs[0, yaw] = -1.0  # the wrap's edge: the angle pi
    obs[1, -3:] = (0.0, 0.0, -1.0)  # pad not visible
    return obs


def test_mirroring_twice_is_the_identity_bit_for_bit(rng: np.random.Generator) -> None:
    mirror = Mirror()
    obs = _observations(rng, 500)
    actions = rng.uniform(-1, 1, size=(500, 4)).astype(np.float32)
    assert mirror.observations(mirror.observations(obs)).tobytes() == obs.tobytes()
    assert mirror.actions(mirror.actions(actions)).tobytes() == actions.tobytes()


def test_a_hand_built_sample_flips_exactly_the_expected_signs() -> None:
    values = np.arange(1, len(OBS_NAMES) + 1, dtype=np.float32) / 20.0  # all distinct, yaw inside (-1, 1)
    mirrored = Mirror().observations(values)
    expected = np.array([EXPECTED_OBS_SIGN[n] for n in OBS_NAMES], np.float32) * values
    assert mirrored.tobytes() == expected.tobytes()
    action = np.array([0.5, -0.25, 0.75, -0.125], np.float32)
    assert Mirror().actions(action).tolist() == (action * EXPECTED_ACTION_SIGN).tolist()


def test_the_yaw_of_pi_stays_in_the_observation_range() -> None:
    obs = np.zeros(len(OBS_NAMES), np.float32)
    obs[OBS_NAMES.index("yaw_rad")] = -1.0
    assert Mirror().observations(obs)[OBS_NAMES.index("yaw_rad")] == -1.0


def test_the_mirror_is_the_world_reflected_east_to_west() -> None:
    """The observation of the reflected world (east, roll, yaw, velocity east, p, r negated; the
    pad as the camera projects it there) is the mirror of the observation of the world."""
    camera = CameraRenderer(CameraConfig(), World(WorldConfig()))
    pad_ned = (0.0, 0.0, -1.5)
    size = (camera.width_px, camera.height_px)

    def observed(sign: float) -> np.ndarray:
        position, attitude = (1.2, sign * 0.9, -5.0), (sign * 0.1, -0.05, sign * 0.7)
        u, v = camera.project(pad_ned, position, attitude)  # type: ignore[misc]
        return Observation(position, attitude, (0.4, sign * -0.6, 0.3), (sign * 0.2, 0.1, sign * -0.3),
                           PadDetection(u, v, 20.0, False), size, 0).to_vector()

    assert np.allclose(Mirror().observations(observed(1.0)), observed(-1.0), atol=1e-6)
    assert Mirror().observations(observed(1.0))[OBS_NAMES.index("pad_u")] != 0.0  # the pad is off-centre


def test_an_unknown_observation_layout_is_refused() -> None:
    with pytest.raises(ConfigError, match="pad_last_u"):
        Mirror((*OBS_NAMES, "pad_last_u"))
    with pytest.raises(ConfigError, match="mirror_augment"):
        Learner(LearnerConfig(mirror_augment=True), HumanDataset(None), obs_dim=16)
    assert mirror_signs(("a", "b"), frozenset({"b"}), frozenset({"a"})).tolist() == [1.0, -1.0]


def _dataset(rng: np.random.Generator, n: int) -> HumanDataset:
    ds = HumanDataset(None)
    obs = _observations(rng, n)
    ds.extend(Sample(0, i, 0.0, Source.DEMONSTRATION, o, np.tanh(o[:4]))
              for i, o in enumerate(obs))
    return ds


def _batches(learner: Learner, updates: int) -> list[tuple[bytes, bytes]]:
    """The minibatches the trainer is handed, as bytes."""
    seen: list[tuple[bytes, bytes]] = []
    real_step = learner.trainer.step

    def spy(obs: np.ndarray, actions: np.ndarray, row_weights: np.ndarray | None = None) -> float:
        assert row_weights is None  # no weighting asked for
        seen.append((obs.tobytes(), actions.tobytes()))
        return real_step(obs, actions)

    learner.trainer.step = spy  # type: ignore[method-assign]
    for _ in range(updates):
        learner.step()
    return seen


@pytest.mark.parametrize("members", [1, 3])
def test_off_the_batches_are_bit_identical_to_todays_rule(rng: np.random.Generator, members: int) -> None:
    """Off (the default, or said): ``batch_size`` rows drawn with replacement by the seeded
    generator, as the learner has always drawn them."""
    ds = _dataset(rng, 300)
    view = ds.view()
    draw = np.random.default_rng(LearnerConfig().seed)
    size = 64 if members == 1 else (members, 64)
    today = []
    for _ in range(20):
        idx = draw.integers(0, len(view), size=size)
        today.append((view.obs[idx].tobytes(), view.actions[idx].tobytes()))
    for cfg in (LearnerConfig(ensemble_members=members),
                LearnerConfig(ensemble_members=members, mirror_augment=False)):
        assert _batches(Learner(cfg, ds), 20) == today


@pytest.mark.parametrize("members", [1, 3])
def test_on_every_batch_holds_each_sample_and_its_mirror(rng: np.random.Generator, members: int) -> None:
    ds = _dataset(rng, 300)
    learner = Learner(LearnerConfig(mirror_augment=True, ensemble_members=members), ds)
    plain = _batches(Learner(LearnerConfig(ensemble_members=members), ds), 5)
    mirror = Mirror()
    shape = (64,) if members == 1 else (members, 64)
    for (obs_b, act_b), (plain_obs, plain_act) in zip(_batches(learner, 5), plain, strict=True):
        obs = np.frombuffer(obs_b, np.float32).reshape(*shape[:-1], 128, len(OBS_NAMES))
        actions = np.frombuffer(act_b, np.float32).reshape(*shape[:-1], 128, 4)
        first, second = obs[..., :64, :], obs[..., 64:, :]
        assert first.tobytes() == plain_obs  # the same draws as with the switch off
        assert second.tobytes() == mirror.observations(first).tobytes()
        assert actions[..., :64, :].tobytes() == plain_act
        assert actions[..., 64:, :].tobytes() == mirror.actions(actions[..., :64, :]).tobytes()


def test_on_the_learner_fits_a_symmetric_policy(rng: np.random.Generator) -> None:
    """Trained on samples from one side only, the policy acts mirrored on the other side."""
    ds = HumanDataset(None)
    obs = _observations(rng, 400)
    obs[:, OBS_NAMES.index("pad_u")] = np.abs(obs[:, OBS_NAMES.index("pad_u")])  # pad always to the right
    act = np.zeros((400, 4), np.float32)
    act[:, 0] = np.tanh(obs[:, OBS_NAMES.index("pad_u")])  # steer right, towards it
    ds.extend(Sample(0, i, 0.0, Source.DEMONSTRATION, o, a) for i, (o, a) in enumerate(zip(obs, act, strict=True)))
    learner = Learner(LearnerConfig(mirror_augment=True, learning_rate=1e-3, max_updates=1500), ds)
    learner.train_until_converged()
    snap = learner.latest_snapshot
    left = Mirror().observations(obs[:50])
    assert np.mean(snap.act(left)[:, 0] < 0) > 0.9  # the pad to the left: steer left
    assert not math.isnan(learner.last_loss)
