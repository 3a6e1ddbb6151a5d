"""MuJoCo's OpenGL backend (``MUJOCO_GL``): what each one needs installed, and a one-line error when the backend a
user set keeps ``import mujoco`` from working at all.

MuJoCo reads ``MUJOCO_GL`` when it is first imported and loads that backend's library then: ``MUJOCO_GL=osmesa`` on a
machine without libOSMesa fails inside PyOpenGL with a 30-line traceback that never says what to install. Only video
recording needs the backend, but with it set wrongly nothing imports; this module imports nothing but the standard
library and the error class, so it can speak first.
"""

from __future__ import annotations

import os

from isaacgymenvs_mw.utils.errors import ConfigError

# What each Linux backend needs (MuJoCo's names; "glfw" or "" opens a window's context, so it needs a display).
_NEEDS = {
    "osmesa": "libOSMesa, for CPU rendering (Debian/Ubuntu: apt-get install libosmesa6)",
    "egl": "libEGL, for GPU rendering (from the NVIDIA driver, or Debian/Ubuntu: apt-get install libegl1)",
    "glfw": "a display (DISPLAY set) and GLFW (pip install glfw)",
}
_GL_VALID = ("osmesa", "egl", "glfw", "glx", "disable")


def gl_install_hint() -> str:
    """How to get a headless backend: the one sentence the import check and the video path both give."""
    return ("Video recording needs an OpenGL backend: on CPU machines OSMesa (Debian/Ubuntu: apt-get install "
            "libosmesa6, then MUJOCO_GL=osmesa or leave MUJOCO_GL unset: isaacgymenvs_mw picks OSMesa when it finds "
            "the library), on NVIDIA GPUs EGL (MUJOCO_GL=egl, libEGL from the driver or apt-get install libegl1). "
            "MUJOCO_GL is read when mujoco is first imported, so set it before the run starts.")


def mujoco_import_error(backend: str, err: BaseException) -> ConfigError:
    """The one line for ``import mujoco`` failing under ``MUJOCO_GL=backend``: what that backend needs, and that
    leaving MUJOCO_GL unset lets training run (only video recording needs a backend)."""
    name = backend.strip().lower()
    cause = (str(err).strip().splitlines() or [""])[-1][:200]
    if name in _NEEDS:
        needs = f"MUJOCO_GL={backend} needs {_NEEDS[name]}"
    else:
        needs = f"MUJOCO_GL={backend!r} is not a backend MuJoCo knows: give one of {list(_GL_VALID)}"
    return ConfigError(
        f"mujoco cannot be imported with MUJOCO_GL={backend!r} ({type(err).__name__}: {cause}): {needs}. Or unset "
        "MUJOCO_GL: isaacgymenvs_mw then picks a backend it finds (or none: only video recording needs one)")


def import_mujoco() -> None:
    """``import mujoco``; where it fails while the user's ``MUJOCO_GL`` names a backend, the one-line ``ConfigError``
    of ``mujoco_import_error`` (the cause kept) instead of PyOpenGL's traceback. A missing mujoco stays as it is."""
    try:
        import mujoco  # noqa: F401
    except Exception as err:  # PyOpenGL raises AttributeError, ImportError, OSError...; MuJoCo a RuntimeError
        backend = os.environ.get("MUJOCO_GL", "")
        if not backend.strip() or (isinstance(err, ModuleNotFoundError) and err.name == "mujoco"):
            raise
        raise mujoco_import_error(backend, err) from err
