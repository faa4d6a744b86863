"""Task layer: the single env (reset/step) and its control, goals, observation, reward and termination.

Its modules import Brax, and Brax imports MJX, which prints "Failed to import warp" where warp-lang is
not installed: MJX is imported here first, through ``hsa_mjx.sim.backend``, which keeps that quiet.
"""

import hsa_mjx.sim.backend  # noqa: F401  (MJX imported quietly, before any Brax import)
