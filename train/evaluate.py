"""Evaluate a trained run or a shipped policy on the device.

``python -m train.evaluate RUN_DIR [--episodes N] [--video]``: loads the run's config and latest
checkpoint and runs N episodes at once with the deterministic policy (its mean action;
``--stochastic`` samples as in training; each env plays exactly one episode).
``python -m train.evaluate --policy NAME_OR_DIR [--episodes N] [--video]``: the same for a policy
directory (``policies/<NAME>`` or a path; ``hsa_mjx/deploy/policy_file.py``), its env rebuilt from its
``policy.json`` and its network run from its ``policy.npz``; defaults sized for a CPU (4 episodes
of at most 1,000 steps).

Prints success rate, mean final distance, mean speed and how the episodes ended (termination
reasons, ``time_out`` at the env's episode limit, ``not_finished`` at a shorter step cap), and
writes eval.json, the diagnostic plots (and with ``--video`` a GIF) into ``--out`` (default
``RUN_DIR/eval/`` or ``runs/eval_<NAME>/``).

``--set env.KEY=VALUE`` (repeatable) evaluates on a changed env, e.g. goals farther than training's
(``--set env.goal.radial_range=[4.0,4.5]``); the observation cannot change.

``--terrain-types all|T1,T2 --levels 0,0.5,1``: instead, ``--episodes`` episodes per terrain type
and difficulty, printed as a table of success rate and net progress and written to
terrain_eval.json and terrain_eval.png (``train/terrain_eval.py``).
"""

from __future__ import annotations

import sys

from hsa_mjx.sim import gl


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m train.evaluate`` (and ``hsa-evaluate``).

    MuJoCo fixes its OpenGL platform when it is first imported, so the offscreen platform for
    ``--video`` is chosen here, before the evaluation (which imports MuJoCo) is.
    """
    gl.choose_platform()
    from .evaluation import run

    return run(argv, description=__doc__)


if __name__ == "__main__":
    sys.exit(main())
