"""Training: Brax PPO over the batched env with the device-side curricula, checkpoints, evaluation.

The source folder is ``train/``; installed, the package is ``hsa_mjx_train`` (docs/architecture.md). Its
modules import each other relatively, so ``python -m train`` in a checkout runs the checkout's code,
installed or not. ``python -m train`` (in a checkout) or ``hsa-train`` trains (``train.cli``); ``python -m
train.evaluate`` or ``hsa-evaluate`` evaluates a run or a shipped policy, ``python -m train.export``
or ``hsa-export`` exports one; ``docs/training.md`` describes them.

Its modules import Brax, and Brax imports MJX, which prints "Failed to import warp" where warp-lang is
not installed: MJX is imported here first, through ``hsa_mjx.sim.backend``, which keeps that quiet.
"""

import hsa_mjx.sim.backend  # noqa: F401  (MJX imported quietly, before any Brax import)
