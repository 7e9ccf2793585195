"""Env lifecycle: every env releases its PyBullet client on close(), so making and closing
many envs in one process neither leaks clients nor grows memory; close() is idempotent."""

from __future__ import annotations

import sys

import gymnasium as gym
import numpy as np
import pybullet
import pytest

import observer_gym.envs  # noqa: F401  (registers the envs)

ENV_ID = "observer_gym/BallTable-v0"
N_ENVS = 100
WARMUP_ENVS = 10
# Allowed growth of the resident set between env WARMUP_ENVS and env N_ENVS. An unclosed
# DIRECT client costs ~28 MB (envs/sim.py), so leaking the 90 clients made after warm-up
# would add ~2.5 GB; 60 MB leaves room for allocator noise and Python-level caches while
# still failing if even ~2 clients' worth of memory leaks.
MAX_RSS_GROWTH_MB = 60.0
# Client ids are small integers reused after disconnect; scan well past any we expect.
MAX_CLIENT_ID_SCANNED = 256


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0  # the value is in kB
    raise RuntimeError("no VmRSS line in /proc/self/status")


def _connected_client_ids() -> set[int]:
    return {
        cid
        for cid in range(MAX_CLIENT_ID_SCANNED)
        if pybullet.getConnectionInfo(physicsClientId=cid)["isConnected"]
    }


@pytest.mark.slow  # many envs (6 s idle)
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")
def test_make_and_close_many_envs_leaks_no_clients_and_no_memory():
    open_before = _connected_client_ids()
    client_ids = []
    rss_after_warmup = None
    action = np.zeros(2, dtype=np.float32)
    for i in range(N_ENVS):
        env = gym.make(ENV_ID, obs_mode="state")
        try:
            env.reset(seed=i)
            env.step(action)
            client_ids.append(env.unwrapped.sim.client_id)
            assert env.unwrapped.sim.is_connected
        finally:
            env.close()
        del env
        if i + 1 == WARMUP_ENVS:
            rss_after_warmup = _rss_mb()
    growth_mb = _rss_mb() - rss_after_warmup
    print(f"\nRSS growth from env {WARMUP_ENVS} to env {N_ENVS}: {growth_mb:.1f} MB")

    still_open = [
        cid
        for cid in client_ids
        if pybullet.getConnectionInfo(physicsClientId=cid)["isConnected"] != 0
    ]
    assert still_open == [], f"clients left connected after close(): {still_open}"
    assert _connected_client_ids() == open_before
    assert growth_mb < MAX_RSS_GROWTH_MB, (
        f"resident memory grew by {growth_mb:.1f} MB over {N_ENVS - WARMUP_ENVS} envs "
        f"(bound {MAX_RSS_GROWTH_MB} MB)"
    )


def test_close_twice_is_safe():
    env = gym.make(ENV_ID, obs_mode="state")
    env.reset(seed=0)
    env.step(np.zeros(2, dtype=np.float32))
    cid = env.unwrapped.sim.client_id
    env.close()
    env.close()
    env.unwrapped.close()
    assert not env.unwrapped.sim.is_connected
    assert pybullet.getConnectionInfo(physicsClientId=cid)["isConnected"] == 0


def test_close_without_reset_is_safe():
    env = gym.make(ENV_ID, obs_mode="state")
    cid = env.unwrapped.sim.client_id
    assert env.unwrapped.sim.is_connected
    env.close()
    assert not env.unwrapped.sim.is_connected
    assert pybullet.getConnectionInfo(physicsClientId=cid)["isConnected"] == 0
    env.close()  # and again
