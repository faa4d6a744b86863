"""Training: Brax PPO over the batched env with the device-side curriculum, checkpoints, evaluation.

``python -m train`` trains (``train.cli``), ``python -m train.evaluate`` evaluates a run or a shipped
policy; ``docs/training.md`` describes both.
"""
