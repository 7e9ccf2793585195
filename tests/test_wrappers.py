"""observer_gym.wrappers (issue 42): the frame stack the package's rgb agents read, a flat
view of the measurements Dicts and a [-1, 1] action view, each against the unwrapped
env's own observations and actions."""

from __future__ import annotations

import warnings

import cv2
import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.wrappers import ResizeObservation
from stable_baselines3.common.env_checker import check_env

from observer_gym.envs import ENV_IDS
from observer_gym.estimation import VisionObserver
from observer_gym.estimation.observer import default_pipeline
from observer_gym.train.rl.agent_env import make_agent_env
from observer_gym.wrappers import FlatObservation, FrameImages, GrayFrameStack, NormalizedAction


class RawObservations(gym.Wrapper):
    """Keeps every observation the wrapped env returns (the ground truth under test)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.seen: list = []

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.seen.append(obs)
        return obs, info

    def step(self, action):
        obs, *rest = self.env.step(action)
        self.seen.append(obs)
        return (obs, *rest)


def grey84(image: np.ndarray) -> np.ndarray:
    small = cv2.resize(image, (84, 84), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)


def random_actions(env: gym.Env, n: int, seed: int = 0) -> list[np.ndarray]:
    space = env.action_space
    rng = np.random.default_rng(seed)
    return [rng.uniform(space.low, space.high).astype(np.float32) for _ in range(n)]


# --- GrayFrameStack ---------------------------------------------------------------------
@pytest.mark.parametrize("env_id", ["observer_gym/BallTable-v0", "observer_gym/TargetFollower-v0"])
def test_frame_stack_is_the_last_four_grey_84px_frames(env_id):
    raw = RawObservations(gym.make(env_id))
    env = GrayFrameStack(raw)
    try:
        assert env.observation_space == spaces.Box(0, 255, (4, 84, 84), np.uint8)
        obs, _ = env.reset(seed=3)
        assert obs.shape == (4, 84, 84) and obs.dtype == np.uint8
        for i in range(4):  # after a reset the first frame fills the stack
            np.testing.assert_array_equal(obs[i], grey84(raw.seen[0]))
        for action in random_actions(env, 6):
            obs, *_ = env.step(action)
            assert env.observation_space.contains(obs)
            for age in range(4):  # obs[-1] is the newest; the reset's frame pads the start
                seen = raw.seen[max(0, len(raw.seen) - 1 - age)]
                np.testing.assert_array_equal(obs[3 - age], grey84(seen))
        assert obs[-1].std() > 0  # a real picture, not a blank
    finally:
        env.close()


def test_frame_resize_is_gymnasiums_resize_observation():
    """The pixels of Gymnasium's ResizeObservation (area interpolation); grey by OpenCV."""
    raw = RawObservations(gym.make("observer_gym/BallTable-v0"))
    ours = FrameImages(raw, size_px=84, grayscale=False)
    try:
        obs, _ = ours.reset(seed=1)
        obs, *_ = ours.step(np.zeros(2, np.float32))
        gymnasiums = ResizeObservation(gym.make("observer_gym/BallTable-v0"), (84, 84))
        reference, _ = gymnasiums.reset(seed=1)
        reference, *_ = gymnasiums.step(np.zeros(2, np.float32))
        gymnasiums.close()
        np.testing.assert_array_equal(obs, reference)
        grey = FrameImages(gym.make("observer_gym/BallTable-v0"), size_px=84)
        grey_obs, _ = grey.reset(seed=1)
        grey_obs, *_ = grey.step(np.zeros(2, np.float32))
        grey.close()
        np.testing.assert_array_equal(grey_obs, cv2.cvtColor(reference, cv2.COLOR_RGB2GRAY))
    finally:
        ours.close()


def test_frame_stack_of_ball_catchers_dict_stacks_each_camera_and_the_ages():
    raw = RawObservations(gym.make("observer_gym/BallCatcher-v1", num_cameras=2))
    env = GrayFrameStack(raw, size_px=64, stack_size=3)
    try:
        space = env.observation_space
        assert isinstance(space, spaces.Dict)
        assert set(space.spaces) == {"camera_0", "camera_1", "frame_age_s"}
        for camera in ("camera_0", "camera_1"):
            assert space[camera] == spaces.Box(0, 255, (3, 64, 64), np.uint8)
        assert space["frame_age_s"].shape == (3, 2)
        obs, _ = env.reset(seed=0)
        for action in random_actions(env, 4):
            obs, *_ = env.step(action)
        assert space.contains(obs)
        for age in range(3):
            seen = raw.seen[-1 - age]
            for camera in ("camera_0", "camera_1"):
                small = cv2.resize(seen[camera], (64, 64), interpolation=cv2.INTER_AREA)
                expected = cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)
                np.testing.assert_array_equal(obs[camera][2 - age], expected)
            np.testing.assert_array_equal(obs["frame_age_s"][2 - age], seen["frame_age_s"])
    finally:
        env.close()


def test_the_packages_rgb_agents_read_the_public_frame_stack():
    """One implementation: an rgb agent's env (no encoder) gives GrayFrameStack's frames."""
    agent_env = make_agent_env("observer_gym/BallTable-v0", "rgb")
    public = GrayFrameStack(gym.make("observer_gym/BallTable-v0"))
    try:
        assert agent_env.observation_space == public.observation_space
        ours, _ = agent_env.reset(seed=5)
        theirs, _ = public.reset(seed=5)
        np.testing.assert_array_equal(ours, theirs)
        for action in random_actions(public, 3):
            ours, *_ = agent_env.step(action / 0.1)  # the agent acts in [-1, 1]
            theirs, *_ = public.step(action)
        np.testing.assert_array_equal(ours, theirs)
    finally:
        agent_env.close()
        public.close()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"size_px": 4}, r"size_px must be an integer in \[8, 512\], got 4"),
        ({"size_px": 84.0}, r"size_px must be an integer in \[8, 512\], got 84.0"),
        ({"size_px": True}, r"size_px must be an integer in \[8, 512\], got True"),
        ({"stack_size": 0}, r"stack_size must be an integer in \[1, 16\], got 0"),
        ({"stack_size": 17}, r"stack_size must be an integer in \[1, 16\], got 17"),
    ],
)
def test_frame_stack_refuses_bad_sizes_naming_the_range(make_env, kwargs, message):
    with pytest.raises(ValueError, match=f"GrayFrameStack {message}"):
        GrayFrameStack(make_env("observer_gym/BallTable-v0"), **kwargs)


def test_frame_wrappers_refuse_an_env_without_images(make_env):
    for mode in ("state", "measurements"):
        with pytest.raises(ValueError, match=r"needs camera images .*obs_mode='rgb'"):
            GrayFrameStack(make_env("observer_gym/BallTable-v0", obs_mode=mode))
    with pytest.raises(ValueError, match="grayscale must be True or False, got 'yes'"):
        FrameImages(make_env("observer_gym/BallTable-v0"), grayscale="yes")


# --- FlatObservation --------------------------------------------------------------------
@pytest.mark.parametrize(
    ("env_id", "kwargs", "expected_layout"),
    [
        (
            "observer_gym/BallTable-v0",
            {},
            {"ball_px": (0, 3), "detected": (3, 5), "table_corners_px": (5, 13)},
        ),
        (
            "observer_gym/BallCatcher-v1",
            {"num_cameras": 3},
            {"detected": (0, 3), "frame_age_s": (3, 6), "uv_px": (6, 12)},
        ),
        (
            "observer_gym/BallCatcher-v1",
            {"num_cameras": 2, "hole_measurements": True},
            {
                "detected": (0, 2),
                "frame_age_s": (2, 4),
                "hole_detected": (4, 6),
                "hole_uv_px": (6, 10),
                "uv_px": (10, 14),
            },
        ),
        ("observer_gym/TargetFollower-v0", {}, {"detected": (0, 1), "target_px": (1, 4)}),
    ],
)
def test_flat_observation_is_the_dicts_entries_in_the_documented_order(
    env_id, kwargs, expected_layout
):
    raw = RawObservations(gym.make(env_id, obs_mode="measurements", **kwargs))
    env = FlatObservation(raw)
    try:
        assert {k: (s.start, s.stop) for k, s in env.layout.items()} == expected_layout
        size = max(stop for _, stop in expected_layout.values())
        space = env.observation_space
        assert isinstance(space, spaces.Box)
        assert space.shape == (size,) and space.dtype == np.float32
        inner = raw.observation_space
        for key, part in env.layout.items():  # the bounds: a Box's, or 0 and 1 for flags
            entry = inner[key]
            if isinstance(entry, spaces.MultiBinary):
                low, high = np.zeros(entry.n), np.ones(entry.n)
            else:
                low, high = entry.low.ravel(), entry.high.ravel()
            np.testing.assert_array_equal(space.low[part], low)
            np.testing.assert_array_equal(space.high[part], high)
        obs, _ = env.reset(seed=2)
        for action in random_actions(env, 5):
            obs, *_ = env.step(action)
            assert obs.shape == (size,) and obs.dtype == np.float32
            assert space.contains(obs)
            for key, part in env.layout.items():
                np.testing.assert_array_equal(obs[part], np.ravel(raw.seen[-1][key]))
        assert obs[env.layout["detected"]].any()  # something was seen: real values compared
    finally:
        env.close()


def test_flat_observation_refuses_a_box_and_camera_images(make_env):
    with pytest.raises(ValueError, match=r"flattens a Dict observation .*obs_mode='measurements'"):
        FlatObservation(make_env("observer_gym/BallTable-v0", obs_mode="state"))
    with pytest.raises(
        ValueError, match=r"not camera images \(entries \['camera_0'.*GrayFrameStack"
    ):
        FlatObservation(make_env("observer_gym/BallCatcher-v1"))


# --- NormalizedAction -------------------------------------------------------------------
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_normalized_action_applies_the_affine_map_in_env_units(env_id):
    env = NormalizedAction(gym.make(env_id, obs_mode="state"))
    try:
        inner = env.env.action_space
        assert env.action_space == spaces.Box(-1.0, 1.0, inner.shape, np.float32)
        env.reset(seed=0)
        for action in random_actions(env, 10, seed=1):
            *_, info = env.step(action)
            expected = inner.low + (action + 1.0) * 0.5 * (inner.high - inner.low)
            np.testing.assert_allclose(info["applied_action"], expected, rtol=1e-6, atol=1e-6)
    finally:
        env.close()


class RecordingPipeline:
    """An observer pipeline that keeps the action each observe() was given."""

    def __init__(self, inner) -> None:
        self.inner, self.actions = inner, []

    def reset(self) -> None:
        self.inner.reset()

    def observe(self, obs, info, action):
        self.actions.append(None if action is None else np.array(action))
        return self.inner.observe(obs, info, action)


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("observer_on_top", [False, True])
def test_an_observer_records_the_applied_action_below_or_above_normalized_action(
    env_id, observer_on_top
):
    base = RawObservations(gym.make(env_id, obs_mode="measurements"))
    recorder = RecordingPipeline(default_pipeline(base))
    if observer_on_top:  # the observer is given the agent's [-1, 1] action
        env = VisionObserver(NormalizedAction(base), pipeline=recorder)
    else:  # the observer is given the action in env units
        env = NormalizedAction(VisionObserver(base, pipeline=recorder))
    try:
        env.reset(seed=0)
        assert recorder.actions == [None]
        applied = []
        actions = [a * 0.9 for a in random_actions(env, 8, seed=2)]
        for action in actions:
            *_, info = env.step(action)
            applied.append(info["applied_action"])
        np.testing.assert_allclose(np.array(recorder.actions[1:]), np.array(applied))
        low, high = base.action_space.low, base.action_space.high
        in_env_units = [low + (a + 1.0) * 0.5 * (high - low) for a in actions]
        np.testing.assert_allclose(np.array(applied), in_env_units, rtol=1e-5, atol=1e-6)
        # not the [-1, 1] action: the record would fail if the observer kept that
        assert not np.allclose(np.array(recorder.actions[1:]), np.array(actions))
    finally:
        env.close()


def _action_warnings(env: gym.Env) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
    return [str(w.message) for w in caught if "action space" in str(w.message)]


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_sb3s_checker_has_no_action_space_warning_with_normalized_action(env_id):
    plain = gym.make(env_id, obs_mode="state")
    wrapped = NormalizedAction(gym.make(env_id, obs_mode="state"))
    flat = NormalizedAction(FlatObservation(gym.make(env_id, obs_mode="measurements")))
    try:
        assert _action_warnings(plain), "the env's own action space draws the warning"
        assert _action_warnings(wrapped) == []
        with warnings.catch_warnings(record=True) as caught:  # nothing at all on the flat view
            warnings.simplefilter("always")
            check_env(flat)
        assert [str(w.message) for w in caught] == []
    finally:
        for env in (plain, wrapped, flat):
            env.close()


def test_normalized_action_refuses_a_space_it_cannot_rescale():
    env = gym.make("CartPole-v1")
    with pytest.raises(ValueError, match=r"needs a float Box action space .*got Discrete"):
        NormalizedAction(env)
    env.close()
    unbounded = gym.make("observer_gym/BallTable-v0", obs_mode="state")
    unbounded.action_space = spaces.Box(-np.inf, np.inf, (2,), np.float32)
    with pytest.raises(ValueError, match="finite bounds, low < high; got Box"):
        NormalizedAction(unbounded)
    unbounded.close()


@pytest.mark.parametrize(
    ("wrap", "obs_mode"),
    [
        (lambda env: GrayFrameStack(env, size_px=64, stack_size=2), "rgb"),
        (lambda env: FrameImages(env, size_px=32, grayscale=False), "rgb"),
        (FlatObservation, "measurements"),
        (NormalizedAction, "state"),
    ],
)
def test_gym_make_rebuilds_a_wrapped_env_from_its_spec(wrap, obs_mode):
    env = wrap(gym.make("observer_gym/BallTable-v0", obs_mode=obs_mode))
    again = gym.make(env.spec)
    try:
        assert type(again) is type(env)
        assert again.observation_space == env.observation_space
        assert again.action_space == env.action_space
    finally:
        env.close()
        again.close()
