"""Training throughput of ``observer-gym train`` (env steps per second, PPO updates
included, evaluation excluded) per obs type, and the cost of each relative to the state.

Each row is a short PPO run of the shipped hyperparameters with evaluation switched off;
what is measured is ``train_steps_per_s`` of its state.json. The vector-env rows show
what SubprocVecEnv buys on this machine for the cheap (state) and dear (rgb) envs.

    python benchmarks/bench_training.py [--env BallTable-v0] [--steps 4096] [--rgb-steps 1024]
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from observer_gym.train.reports.outputs import format_table
from observer_gym.train.rl.training import train_agent

# (label, obs, estimate_from, n_envs, vec_env, hyperparameter overrides); the rgb rows
# read 84 x 84 frames: through the YAML's frame encoder (BallTable) or, with the encoder
# switched off, through SB3's CnnPolicy trained by PPO
CNN = {"image.encoder": None}
CASES = (
    ("state", "state", "measurements", 1, "dummy", {}),
    ("estimate (measurements)", "estimate", "measurements", 1, "dummy", {}),
    ("estimate (rgb)", "estimate", "rgb", 1, "dummy", {}),
    ("rgb (YAML's image options)", "rgb", "measurements", 1, "dummy", {}),
    ("rgb, CnnPolicy (4 stacked frames)", "rgb", "measurements", 1, "dummy", CNN),
    ("state, 2 subproc envs", "state", "measurements", 2, "subproc", {}),
    ("rgb (YAML's), 2 subproc envs", "rgb", "measurements", 2, "subproc", {}),
    ("rgb, CnnPolicy, 2 subproc envs", "rgb", "measurements", 2, "subproc", CNN),
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="BallTable-v0")
    parser.add_argument("--steps", type=int, default=4096, help="steps of the vector rows")
    parser.add_argument("--rgb-steps", type=int, default=1024, help="steps of the pixel rows")
    args = parser.parse_args()
    rows, rates = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for i, (label, obs, source, n_envs, vec_env, overrides) in enumerate(CASES):
            pixels = obs == "rgb" or source == "rgb"
            steps = args.rgb_steps if pixels else args.steps
            state = train_agent(
                args.env,
                "ppo",
                obs,
                Path(tmp) / str(i),
                timesteps=steps,
                estimate_from=source,
                n_envs=n_envs,
                vec_env=vec_env,
                hyperparams={"n_steps": 256 if pixels else 512, "eval_freq": 10**9, **overrides},
                progress=False,
            )
            rates[label] = state["train_steps_per_s"]
            rows.append([label, str(n_envs), f"{state['timesteps']}", f"{rates[label]:.0f}"])
    base = rates["state"]
    for row in rows:
        row.append(f"{base / rates[row[0]]:.1f}")
    print(f"\nPPO training throughput on {args.env}, {os.cpu_count()} CPU(s), one run:")
    print(format_table(["obs", "envs", "steps", "env steps/s", "cost vs state"], rows))


if __name__ == "__main__":
    main()
