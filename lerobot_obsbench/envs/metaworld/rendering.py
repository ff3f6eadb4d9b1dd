"""MuJoCo's headless OpenGL for Meta-World's cameras: EGL (Mesa's llvmpipe on a CPU-only machine, the GPU's driver
on a GPU node) or OSMesa, chosen through `MUJOCO_GL` before MuJoCo is imported, and checked by opening a context
before anything slow starts."""

from __future__ import annotations

import atexit
import gc
import os
import sys
import weakref

from lerobot_obsbench.errors import ObsBenchError

HEADLESS_GL = ("egl", "osmesa")
GL_HELP = (
    "install Mesa's EGL (Debian: apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri; `bash "
    "scripts/setup_system.sh` does) and leave MUJOCO_GL unset or set it to egl, or install OSMesa (libosmesa6) and "
    "set MUJOCO_GL=osmesa"
)


class HeadlessGLError(ObsBenchError, RuntimeError):
    """MuJoCo could not open an OpenGL context without a display."""


def prefer_headless_gl() -> None:
    """Point MuJoCo (and PyOpenGL) at EGL unless `MUJOCO_GL` is set: MuJoCo reads it once, when first imported."""
    chosen = os.environ.setdefault("MUJOCO_GL", "egl")
    if chosen in HEADLESS_GL:
        os.environ.setdefault("PYOPENGL_PLATFORM", chosen)


def choose_gl() -> str:
    """The OpenGL back-end MuJoCo will use: `MUJOCO_GL` as set (egl, osmesa, or glfw with a display), else egl.
    Must run before MuJoCo is imported."""
    prefer_headless_gl()
    chosen = os.environ["MUJOCO_GL"]
    if chosen not in (*HEADLESS_GL, "glfw"):
        raise HeadlessGLError(f"MUJOCO_GL={chosen!r} is not one of MuJoCo's back-ends (egl, osmesa, glfw); {GL_HELP}")
    return chosen


def check_gl() -> None:
    """Open and free a 1x1 OpenGL context, so a machine without headless GL is refused in one line before a
    simulator is built. A context MuJoCo failed to open cannot free itself either: its complaint, printed when it
    is collected, is kept quiet, so the refusal stays the one line."""
    backend = choose_gl()
    failure = None
    hook = sys.unraisablehook
    sys.unraisablehook = lambda unraisable: None
    try:
        try:
            import mujoco

            if mujoco.GLContext.__module__ != f"mujoco.{backend}":
                raise RuntimeError(
                    f"MuJoCo was imported with {mujoco.GLContext.__module__} before its back-end was chosen (set "
                    f"MUJOCO_GL={backend} before Python starts)"
                )
            context = mujoco.GLContext(1, 1)
            context.make_current()
            context.free()
        except Exception as err:  # MuJoCo and PyOpenGL raise ImportError, RuntimeError or their own errors
            failure = f"{type(err).__name__}: {err}"
        gc.collect()  # the half-opened context, whose last reference the handled error held
    finally:
        sys.unraisablehook = hook
    if failure is not None:
        raise HeadlessGLError(
            f"MuJoCo could not open an OpenGL context with MUJOCO_GL={backend} ({failure}); {GL_HELP}"
        )


_open_renderers: weakref.WeakSet = weakref.WeakSet()


def open_renderer(model, height: int, width: int):
    """A `mujoco.Renderer`, closed when the env closes it or, at the latest, when the interpreter exits: before
    MuJoCo terminates its EGL display (a renderer freed after that complains at exit), since this exit hook is
    registered after MuJoCo's and exit hooks run last first. The model's offscreen framebuffer (Meta-World's scene
    asks for 640 x 480) is widened to the image asked for, which MuJoCo would otherwise refuse."""
    import mujoco

    visual = model.vis.global_
    visual.offwidth, visual.offheight = max(visual.offwidth, width), max(visual.offheight, height)
    renderer = mujoco.Renderer(model, height, width)
    if not _open_renderers:
        atexit.unregister(_close_open_renderers)
        atexit.register(_close_open_renderers)
    _open_renderers.add(renderer)
    return renderer


def _close_open_renderers() -> None:
    for renderer in list(_open_renderers):
        renderer.close()
