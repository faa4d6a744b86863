"""Deployment: the exported policy as a numpy network (no JAX)."""
