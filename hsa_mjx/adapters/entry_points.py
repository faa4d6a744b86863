"""Gymnasium's entry points of ``hsa_mjx/HSA-v0``: choose MuJoCo's offscreen GL platform, then build the env.

MuJoCo fixes its OpenGL platform when ``mujoco`` is first imported, and the adapters import it, so
these functions set ``MUJOCO_GL`` for a headless machine (``hsa_mjx.sim.gl.choose_platform``: only
when it is unset and no display exists) before they import the adapter. Importing this module
changes nothing; creating an env through Gymnasium does that one thing.

Gymnasium's ``async`` vectorization builds one env in the calling process (to read its spaces), then
starts its workers. Forked from a process where JAX runs, a worker deadlocks (JAX's threads do not
survive a fork), so an env asked for in a forked copy of a process that built one here is refused
with a ``RuntimeError`` that says what to pass instead: ``vector_kwargs={"context": "spawn"}``
(the workers then start clean; the script needs the usual ``if __name__ == "__main__":`` guard).
"""

from __future__ import annotations

import os
from typing import Any

from hsa_mjx.sim import gl

SPAWN = {"context": "spawn"}  # gymnasium.make_vec(..., vectorization_mode="async", vector_kwargs=SPAWN)
_built_in: list[int] = []  # the process that built an env through these entry points (JAX runs in it)


def check_not_forked() -> None:
    """Refuse to build an env in a forked copy of a process that built one (it would deadlock)."""
    if _built_in and _built_in[0] != os.getpid():
        raise RuntimeError(
            "hsa_mjx/HSA-v0 in a worker forked from a process that runs JAX would deadlock; start the "
            "workers with spawn: gymnasium.make_vec(..., vectorization_mode='async', "
            "vector_kwargs={'context': 'spawn'}) (and keep the script's code under "
            "if __name__ == '__main__':)"
        )
    if not _built_in:
        _built_in.append(os.getpid())


def single_env(**kwargs: Any) -> Any:
    """``gymnasium.make("hsa_mjx/HSA-v0", ...)``: :func:`hsa_mjx.adapters.gymnasium.from_registry`."""
    check_not_forked()
    gl.choose_platform()
    from hsa_mjx.adapters.gymnasium import from_registry

    return from_registry(**kwargs)


def vector_env(num_envs: int = 1, **kwargs: Any) -> Any:
    """``gymnasium.make_vec("hsa_mjx/HSA-v0", ...)``: :func:`hsa_mjx.adapters.gymnasium_vector.make_vector_env`."""
    check_not_forked()
    gl.choose_platform()
    from hsa_mjx.adapters.gymnasium_vector import make_vector_env

    return make_vector_env(num_envs, **kwargs)
