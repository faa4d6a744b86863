"""MuJoCo's OpenGL platform for offscreen frames, chosen before ``mujoco`` is first imported.

MuJoCo reads ``MUJOCO_GL`` once, when ``mujoco`` is imported, and without it uses GLFW, which
needs a display: on a headless machine rendering would fail. ``choose_platform`` sets ``MUJOCO_GL``
when it is unset and no display exists: ``egl`` where the EGL library is found, else ``osmesa``
where OSMesa is, else nothing (MuJoCo's default); a ``MUJOCO_GL`` the user set is kept. Importing
hsa_mjx changes nothing: ``hsa_mjx.make_env``, the Gymnasium entry points and the command-line tools
call it before they import ``mujoco``. A program that imports ``mujoco`` itself first fixes the
platform then: set ``MUJOCO_GL`` before that import.
"""

from __future__ import annotations

import ctypes.util
import os
from collections.abc import MutableMapping

OFFSCREEN = (("egl", "EGL"), ("osmesa", "OSMesa"))  # (MUJOCO_GL value, library), in order of preference


def has_display(environ: MutableMapping[str, str] = os.environ) -> bool:
    """Whether an X11 or Wayland display is set."""
    return bool(environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY"))


def choose_platform(environ: MutableMapping[str, str] = os.environ) -> str | None:
    """Set ``MUJOCO_GL`` for a headless machine as described above; the platform in force (None: MuJoCo's)."""
    if environ.get("MUJOCO_GL"):
        return environ["MUJOCO_GL"]
    if has_display(environ):
        return None
    for platform, library in OFFSCREEN:
        if ctypes.util.find_library(library):
            environ["MUJOCO_GL"] = platform
            return platform
    return None
