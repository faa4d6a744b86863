"""Batch layer: many envs stepped in one call, with auto-reset and per-env episode bookkeeping."""
