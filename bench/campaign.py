"""Record a campaign of many small CartPole evidence files, as a fleet of evaluation jobs would.

    python bench/campaign.py OUT_DIR [--files 2000] [--seed 0]

Each file is one ``RecordEvidence`` around ``gym.make("CartPole-v1")`` with 1 to 5 episodes of
random actions (seeded: the same campaign each time). ``report`` (and ``report --html``) over
2 000 such files is the campaign-scale case of docs/scale.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import numpy as np

from episode_audit import RecordEvidence


def record_campaign(out: Path, files: int = 2000, seed: int = 0) -> list[Path]:
    """Record ``files`` CartPole files under ``out``; return their paths."""
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    paths = []
    for i in range(files):
        path = out / f"run-{i:05d}.mcap"
        with RecordEvidence(gym.make("CartPole-v1"), path, overwrite=True) as env:
            env.action_space.seed(seed + i)
            for k in range(int(rng.integers(1, 6))):
                env.reset(seed=seed + 10 * i + k)
                done = False
                while not done:
                    _, _, terminated, truncated, _ = env.step(env.action_space.sample())
                    done = terminated or truncated
        paths.append(path)
    return paths


def main() -> None:
    """Parse the command line and record the campaign."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--files", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    paths = record_campaign(args.out, args.files, args.seed)
    size = sum(p.stat().st_size for p in paths)
    print(f"{len(paths)} files, {size / 1e6:.1f} MB in {args.out}")


if __name__ == "__main__":
    main()
