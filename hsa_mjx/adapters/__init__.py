"""Adapters from HSAEnv to other APIs (Gymnasium)."""
