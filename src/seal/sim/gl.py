"""Headless OpenGL set-up. Import this before anything imports mujoco.

MuJoCo picks its GL backend from ``MUJOCO_GL`` when it is first imported, so the default
has to be in place before that. We default to EGL (works headless, CPU Mesa included) and
never override a user's explicit choice.
"""

from __future__ import annotations

import atexit
import logging
import os
import weakref

os.environ.setdefault("MUJOCO_GL", "egl")
if os.environ["MUJOCO_GL"] in ("egl", "osmesa"):
    os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

# robosuite warns on import that no private macro file exists; nothing a SEAL user can act on.
logging.getLogger("robosuite_logs").addFilter(lambda record: "macro" not in record.getMessage())

_live: "weakref.WeakSet" = weakref.WeakSet()
_registered = False


def track(closeable) -> None:
    """Close ``closeable`` at interpreter exit unless it was closed before.

    GL contexts freed by ``__del__`` during interpreter teardown raise ``EGLError``
    tracebacks once the EGL library is half unloaded; closing them from ``atexit``
    (which runs first) keeps exit quiet. The hook is registered on first use, i.e. after
    mujoco's EGL module registered its own ``eglTerminate`` hook, so that ours runs before it
    (``atexit`` runs last-registered first).
    """
    global _registered
    _live.add(closeable)
    if not _registered:
        atexit.register(_close_all)
        _registered = True


def _close_all() -> None:
    for obj in list(_live):
        try:
            obj.close()
        except Exception:  # noqa: BLE001 - best effort at exit, nothing to report to
            pass
