"""System identification of the robot's servos: a test signal, logs, the lifted rig, and the fit.

``python -m hsa_mjx.sysid`` (``signal``, ``synth``, ``fit``); the log format: ``hsa_mjx.sysid.logs``.
"""
