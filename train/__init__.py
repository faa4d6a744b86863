"""Training: Brax PPO over the batched env with the device-side curricula, checkpoints, evaluation.

The source folder is ``train/``; installed, the package is ``hsa_mjx_train`` (docs/architecture.md). Its
modules import each other relatively, so ``python -m train`` in a checkout runs the checkout's code,
installed or not. ``python -m train`` (in a checkout) or ``hsa-train`` trains (``train.cli``); ``python -m
train.evaluate`` or ``hsa-evaluate`` evaluates a run or a shipped policy, ``python -m train.export``
or ``hsa-export`` exports one; ``docs/training.md`` describes them.

Importing the package imports neither MuJoCo nor Brax: ``python -m train.evaluate --video`` chooses
MuJoCo's offscreen platform before MuJoCo is first imported. Brax imports MJX, which prints "Failed to
import warp" where warp-lang is not installed: each module that imports Brax imports MJX first, through
``hsa_mjx.sim.backend``, which keeps that quiet.
"""
