"""The latency sweep of docs/your_method.md from Python: mylab's alpha-beta observer and
PD controller against observer-gym's kf and ekf, on the same seeds.

    python examples/your_method/sweep.py --out runs/your_method [--episodes 10] [--workers 2]

(with examples/your_method on the Python path, or the folder installed).
"""

import argparse

from mylab.control import make_controller
from mylab.filters import make_observer

import observer_gym

make_observer.obs_mode = "measurements"  # read the perfect detector's pixels, not frames

if __name__ == "__main__":  # worker processes import this file: run the sweep only here
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--steps", type=int, default=None, help="cap on each episode's steps")
    args = parser.parse_args()
    result = observer_gym.sweep(
        "BallTable-v0",
        vary={"latency_s": [0.0, 0.02, 0.05, 0.1]},
        observers=["kf-measurements", "ekf-measurements", make_observer],
        controllers=["lqr", make_controller],
        episodes=args.episodes,
        workers=args.workers,
        steps=args.steps,
        out_dir=args.out,
    )
    print(result.text)
    for cell in result.cells:
        distance = cell["statistics"]["mean_distance_m"]["mean"]
        print(cell["point"], cell["observer"], cell["controller"], f"{1e3 * distance:.2f} mm")
