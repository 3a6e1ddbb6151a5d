"""Offscreen video of one world: MuJoCo's renderer on a host copy of that world's state, written as mp4 clips.

A ``VideoRecorder`` is told each env step (``capture(step)``). Every ``every`` steps it records ``length`` steps:
for each of those it copies the world's qpos/qvel from the device into a host ``MjData`` (a device->host sync),
runs ``mj_forward`` there, renders one frame and streams it to ffmpeg. Between clips ``capture`` only compares two
Python integers, so a run that records rarely pays almost nothing for it.

Headless rendering needs an OpenGL backend. MuJoCo picks one from ``MUJOCO_GL`` when it is first imported, and
loading one is not free: OSMesa brings its own LLVM, which crashed processes that then loaded Triton (a CUDA build
of torch on a CPU-only machine). So nothing is chosen at import; the first recorder chooses (``choose_gl_backend``:
EGL on NVIDIA machines, OSMesa on others, only without a display and only where the user set no ``MUJOCO_GL``) and
hands MuJoCo that backend's context class (``_install_gl_backend``).
"""

from __future__ import annotations

import copy
import importlib
import math
import os
import subprocess
import sys
import weakref
from pathlib import Path
from typing import Callable

import mujoco
import numpy as np

from isaacgymenvs_mw.sim.gl import gl_install_hint
from isaacgymenvs_mw.sim.simulator import Simulator
from isaacgymenvs_mw.sim.terrain import ground_geoms
from isaacgymenvs_mw.utils.config import check_entry, real_number
from isaacgymenvs_mw.utils.errors import ConfigError

_BODY_RGBA = np.array([0.85, 0.55, 0.25, 1.0])
_GROUND_RGBA = np.array([0.22, 0.27, 0.32, 1.0])
_GRID_RGBA = np.array([0.55, 0.6, 0.65, 1.0], dtype=np.float32)
_GRID_SPACING = 0.5  # m
_NEAR_CLIP_M, _FAR_CLIP_M = 0.05, 1000.0  # at most; small models keep MuJoCo's own (extent-scaled) planes

AUTO = "auto"  # track_body default: the floating base's body when there is one, a fixed view otherwise
VIEW_KEY = "task.env.videoCamera"  # a task's own camera for its videos: {eye: [x, y, z], lookat: [x, y, z]} (m)


def camera_view(value, key: str = VIEW_KEY) -> tuple[np.ndarray, np.ndarray] | None:
    """A task's video camera, ``{eye, lookat}`` in world coordinates (m), as (eye, lookat); None where not given.
    Scenes the automatic framing cannot see into (Trifinger's arena, whose wall hides the cube from a side view)
    give one."""
    if value is None:
        return None
    check_entry(value, key, ("eye", "lookat"))
    points = []
    for name in ("eye", "lookat"):
        point = value.get(name)
        if isinstance(point, (str, bytes)) or not hasattr(point, "__len__") or len(point) != 3:
            raise ConfigError(f"{key}.{name}={point!r} is invalid: give a point [x, y, z] in metres")
        points.append(np.array([real_number(c, f"{key}.{name}") for c in point]))
    if np.linalg.norm(points[0] - points[1]) < 1e-6:
        raise ConfigError(f"{key}: eye and lookat are the same point {points[0].tolist()}: give the camera a "
                          "position apart from what it looks at")
    return points[0], points[1]

# A throwaway process opens a context with the backend this process would use: a backend that cannot start may
# abort the process that tries (MuJoCo's GLFW does on a second try without a display), so this one never tries
# an unproven backend, and remembers the verdict.
_PROBE = """
import mujoco
from isaacgymenvs_mw.utils.config import check_entry, real_number
from isaacgymenvs_mw.utils.errors import ConfigError
model = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size=".1"/></worldbody></mujoco>')
renderer = mujoco.Renderer(model, height=8, width=8)
renderer.render()
renderer.close()
"""
_gl_verdict: dict[str, str | None] = {}  # "error": None once the backend works, the message when it does not


def _gl_error_message(reason: str) -> str:
    backend = os.environ.get("MUJOCO_GL", "")
    named = f"MUJOCO_GL={backend!r}" if backend else "MUJOCO_GL unset (GLFW, which needs a display)"
    return f"MuJoCo's offscreen renderer cannot start with {named}: {reason}. {gl_install_hint()}"


def choose_gl_backend() -> None:
    """Set ``MUJOCO_GL`` for offscreen rendering where the user set none: only on Linux without a display (a display
    keeps MuJoCo's default, GLFW), EGL where an NVIDIA GPU is visible, OSMesa otherwise; a backend whose library is
    missing is not chosen (the probe then says what to install)."""
    if os.environ.get("MUJOCO_GL") or not sys.platform.startswith("linux"):
        return
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return
    from ctypes.util import find_library

    if os.path.exists("/dev/nvidia0") and find_library("EGL"):
        os.environ["MUJOCO_GL"] = "egl"
    elif find_library("OSMesa"):
        os.environ["MUJOCO_GL"] = "osmesa"


def _install_gl_backend() -> None:
    """Give MuJoCo the context class of the backend ``MUJOCO_GL`` names now, where mujoco was imported before it was
    chosen (it keeps the class it picked then; mujoco==4.0.0's Renderer reads it from ``gl_context`` when made)."""
    chosen = os.environ.get("MUJOCO_GL", "").lower().strip()
    from mujoco.rendering.classic import gl_context

    if chosen in ("egl", "osmesa") and getattr(gl_context, "_MUJOCO_GL", chosen) != chosen:
        gl_context.GLContext = importlib.import_module(f"mujoco.{chosen}").GLContext
        gl_context._MUJOCO_GL = chosen


def gl_backend_error() -> str | None:
    """Why MuJoCo's offscreen renderer cannot start here (None if it can). Chooses the backend first; probed once per
    process."""
    choose_gl_backend()
    if "error" not in _gl_verdict:
        try:
            proc = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=120,
                                  env=os.environ.copy())
            ok, detail = proc.returncode == 0, (proc.stderr.strip().splitlines() or [f"exit status {proc.returncode}"])
            reason = None if ok else detail[-1][-300:]
        except (OSError, subprocess.TimeoutExpired) as err:
            reason = f"the test process failed ({err})"
        _gl_verdict["error"] = None if reason is None else _gl_error_message(reason)
    return _gl_verdict["error"]


class GLBackendError(RuntimeError):
    """No OpenGL backend can start here; the message says what to install."""


def _start_renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    """A renderer, or the same clear GLBackendError on every attempt where no GL backend works."""
    error = gl_backend_error()
    if error is None:
        try:
            _install_gl_backend()
            return mujoco.Renderer(model, height=height, width=width)
        except Exception as err:  # noqa: BLE001  (the probe passed, this process did not: remember it)
            _gl_verdict["error"] = error = _gl_error_message(f"{type(err).__name__}: {err}")
    raise GLBackendError(error)


class VideoRecorder:
    """Records world ``world`` of ``sim`` into ``out_dir/video_<step>.mp4``, ``length`` frames every ``every`` steps.

    Args:
        sim: the simulator whose world is filmed.
        out_dir: folder for the clips (created on the first clip).
        fps: frame rate of the files; one frame per env step, so 1 / control dt is real time.
        width, height: frame size in pixels (even numbers: H.264 in yuv420p needs them).
        track_body: "auto" follows the root body of a floating-base model and frames a fixed-base model from the
            side; a body name follows that body; None always uses the fixed view.
        every: a clip starts at env steps 1, 1 + every, 1 + 2 * every, ... (IsaacGymEnvs' capture_video_freq).
        length: frames (env steps) per clip (IsaacGymEnvs' capture_video_len).
        world: which world to film.
        beside: returns an (h, w, 3) uint8 picture to show to the right of each frame (what the policy sees: a
            task's camera images); it is scaled up by a whole factor to fit the frame's height. None: the view alone.
        view: (eye, lookat), world points (m): a fixed camera at eye looking at lookat (``camera_view``), in place of
            the automatic framing; nothing is tracked then.
    """

    def __init__(
        self,
        sim: Simulator,
        out_dir: str | os.PathLike,
        fps: float,
        width: int = 640,
        height: int = 480,
        track_body: str | None = AUTO,
        every: int = 1464,
        length: int = 100,
        world: int = 0,
        beside: Callable[[], np.ndarray] | None = None,
        view: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        if int(every) < 1 or int(length) < 1:
            raise ConfigError(f"capture_video_freq and capture_video_len must be >= 1, got {every} and {length}")
        if width < 2 or height < 2 or width % 2 or height % 2:
            raise ValueError(f"video width and height must be even numbers >= 2, got {width}x{height}")
        if not (fps > 0 and math.isfinite(fps)):
            raise ValueError(f"video fps must be a positive number, got {fps}")
        if not 0 <= world < sim.num_worlds:
            raise ValueError(f"world {world} is out of range: the simulator has {sim.num_worlds} worlds")
        self.sim = sim
        self.out_dir = Path(out_dir)
        self.fps = float(fps)
        self.width, self.height = int(width), int(height)
        self.every, self.length = int(every), int(length)
        self.world = int(world)
        self.written: list[Path] = []
        self.beside = beside
        # The frame written: the view, then the picture beside it (its width fixed now, from its shape).
        self.frame_width = self.width + (self._beside_frame().shape[1] if beside is not None else 0)

        # A private copy: the offscreen buffer size is a model field, and the sim's host model stays untouched.
        self.model = copy.copy(sim.mj_model)
        self.model.vis.global_.offwidth = max(self.width, int(self.model.vis.global_.offwidth))
        self.model.vis.global_.offheight = max(self.height, int(self.model.vis.global_.offheight))
        self._ground = _ground_ids(self.model)  # styled as ground and left out of the camera's framing
        self._style_model()
        self.data = mujoco.MjData(self.model)
        self._copy_mocap()  # where the task has put its mocap bodies (a goal marker) so far
        mujoco.mj_forward(self.model, self.data)  # qpos0: used to frame the model
        self._planes = [g for g in range(self.model.ngeom)
                        if int(self.model.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_PLANE)]

        self.view = view
        self.track_body_id = None if view is not None else self._tracked_body(track_body)
        self.camera = self._make_camera()
        self.renderer = _start_renderer(self.model, self.height, self.width)
        # Release the GL context at the latest when the interpreter exits (MuJoCo's own __del__ fails then).
        self._release = weakref.finalize(self, self.renderer.close)
        self._writer = None
        self._clip_start = 0
        self._clip_frames = 0
        self._clip_part: Path | None = None

    # ------------------------------------------------------------------- looks
    def _style_model(self) -> None:
        """Make the copy readable on film: a brighter headlight (models built here have no lights), the robot in
        a warm colour and the ground in a cool one where the asset left MuJoCo's default grey."""
        m = self.model
        m.vis.headlight.ambient[:] = 0.35
        m.vis.headlight.diffuse[:] = 0.65
        m.vis.headlight.specular[:] = 0.15
        # MuJoCo's clip planes scale with the model's extent; a terrain's 300 m put the near one at 3 m, where the
        # tracking camera stands, and cut the robot away. Fixed distances instead, for any model size.
        m.vis.map.znear = min(float(m.vis.map.znear), _NEAR_CLIP_M / float(m.stat.extent))
        m.vis.map.zfar = min(float(m.vis.map.zfar), _FAR_CLIP_M / float(m.stat.extent))
        default_grey = np.array([0.5, 0.5, 0.5, 1.0])
        for g in range(m.ngeom):
            if not np.allclose(m.geom_rgba[g], default_grey) or int(m.geom_matid[g]) >= 0:
                continue  # the asset chose a colour or material: keep it
            m.geom_rgba[g] = _GROUND_RGBA if g in self._ground else _BODY_RGBA

    def _add_floor_grid(self) -> None:
        """Draw grid lines on each horizontal plane around the camera's target: without them a tracked robot
        on a plain floor seems to walk on the spot."""
        scene = self.renderer.scene
        spacing = _GRID_SPACING
        reach = math.ceil(2.5 * self.camera.distance / spacing) * spacing
        cx = round(float(self.camera.lookat[0]) / spacing) * spacing
        cy = round(float(self.camera.lookat[1]) / spacing) * spacing
        offsets = np.arange(-reach, reach + spacing / 2, spacing)
        for g in self._planes:
            normal = self.data.geom_xmat[g].reshape(3, 3)[:, 2]
            if normal[2] < 0.99:
                continue  # only level ground
            z = float(self.data.geom_xpos[g][2]) + 1e-3
            for k in offsets:
                for a, b in (((cx + k, cy - reach, z), (cx + k, cy + reach, z)),
                             ((cx - reach, cy + k, z), (cx + reach, cy + k, z))):
                    if scene.ngeom >= scene.maxgeom:
                        return
                    geom = scene.geoms[scene.ngeom]
                    mujoco.mjv_initGeom(geom, int(mujoco.mjtGeom.mjGEOM_LINE), np.zeros(3), np.zeros(3),
                                        np.eye(3).ravel(), _GRID_RGBA)
                    mujoco.mjv_connector(geom, int(mujoco.mjtGeom.mjGEOM_LINE), 1.5,
                                         np.array(a, dtype=float), np.array(b, dtype=float))
                    scene.ngeom += 1

    # ------------------------------------------------------------------ camera
    def _tracked_body(self, track_body: str | None) -> int | None:
        if track_body is None:
            return None
        if track_body == AUTO:
            if not self.sim.floating_base:
                return None
            return int(self.model.jnt_bodyid[0])  # the body that carries the free joint
        return self.sim.body_id(track_body)

    def _model_box(self) -> tuple[np.ndarray, np.ndarray]:
        """World-frame bounding box (lo, hi) of every geom but the ground (planes, the terrain's parts), at the
        model's initial pose: the camera frames the robot, not a 100 m terrain."""
        m, d = self.model, self.data
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
        corners = []
        for g in range(m.ngeom):
            if g in self._ground:
                continue
            center, half = m.geom_aabb[g, :3], m.geom_aabb[g, 3:]
            local = center + signs * half
            corners.append(d.geom_xpos[g] + local @ d.geom_xmat[g].reshape(3, 3).T)
        if not corners:
            return np.full(3, -0.5), np.full(3, 0.5)
        pts = np.concatenate(corners)
        return pts.min(axis=0), pts.max(axis=0)

    def _make_camera(self) -> mujoco.MjvCamera:
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        if self.view is not None:
            # MuJoCo's free camera sits at lookat - distance * (cos el cos az, cos el sin az, sin el)
            eye, lookat = self.view
            forward = lookat - eye
            cam.distance = float(np.linalg.norm(forward))
            cam.azimuth = math.degrees(math.atan2(forward[1], forward[0]))
            cam.elevation = math.degrees(math.asin(float(forward[2]) / cam.distance))
            cam.lookat[:] = lookat
            return cam
        lo, hi = self._model_box()
        size = hi - lo
        if self.track_body_id is not None:
            # Three-quarter view from the robot's front right (+x, -y), at a distance that fits it a few times
            # over; lookat follows the body each frame (set in _sync).
            cam.azimuth, cam.elevation = 135.0, -20.0
            cam.distance = max(1.0, 3.0 * float(np.max(size)))
            cam.lookat[:] = self.data.xpos[self.track_body_id]
            return cam
        # Fixed side view: look across the longer horizontal axis, far enough back that the whole model fits.
        center = (lo + hi) / 2
        along_y = size[1] >= size[0]
        cam.azimuth = 180.0 if along_y else 90.0  # 180: camera on +x looking at -x; 90: on -y looking at +y
        cam.elevation = -10.0
        half_w = size[1] / 2 if along_y else size[0] / 2
        half_depth = size[0] / 2 if along_y else size[1] / 2
        half_h = size[2] / 2
        tan_v = math.tan(math.radians(float(self.model.vis.global_.fovy)) / 2)
        tan_h = tan_v * self.width / self.height
        cam.distance = 1.15 * max(half_w / tan_h, half_h / tan_v, 0.5) + half_depth
        cam.lookat[:] = center
        return cam

    # --------------------------------------------------------------- rendering
    def _sync(self) -> None:
        """World ``self.world``'s state from the device into the host MjData (a device->host copy: a sync)."""
        self.data.qpos[:] = self.sim.qpos[self.world].detach().cpu().numpy()
        self.data.qvel[:] = self.sim.qvel[self.world].detach().cpu().numpy()
        self._copy_mocap()
        mujoco.mj_forward(self.model, self.data)
        if self.track_body_id is not None:
            self.camera.lookat[:] = self.data.xpos[self.track_body_id]

    def _copy_mocap(self) -> None:
        """Mocap bodies are moved by the task, not by qpos: their poses come from the device too."""
        if self.model.nmocap:
            self.data.mocap_pos[:] = self.sim.mocap_pos[self.world].detach().cpu().numpy()
            self.data.mocap_quat[:] = self.sim.mocap_quat[self.world].detach().cpu().numpy()

    def render(self, segmentation: bool = False) -> np.ndarray:
        """One frame of the world as it is now on the device: (height, width, 3) uint8 RGB.

        With ``segmentation=True``: (height, width) int32 geom ids, -1 where no geom of the model is seen.
        """
        self._sync()
        if segmentation:
            self.renderer.enable_segmentation_rendering()
            try:
                self.renderer.update_scene(self.data, camera=self.camera)
                seg = self.renderer.render()
            finally:
                self.renderer.disable_segmentation_rendering()
            is_geom = seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)
            return np.where(is_geom, seg[..., 0], -1).astype(np.int32)
        self.renderer.update_scene(self.data, camera=self.camera)
        self._add_floor_grid()
        return self.renderer.render()

    def _beside_frame(self) -> np.ndarray:
        """``beside()``'s picture scaled up by the largest whole factor that fits the frame's height (pixels stay
        sharp), centred vertically on black, an even number of columns wide (H.264 in yuv420p needs it)."""
        picture = np.asarray(self.beside(), dtype=np.uint8)
        scale = max(1, self.height // picture.shape[0])
        picture = np.repeat(np.repeat(picture, scale, axis=0), scale, axis=1)[:self.height]
        out = np.zeros((self.height, picture.shape[1] + picture.shape[1] % 2, 3), dtype=np.uint8)
        top = (self.height - picture.shape[0]) // 2
        out[top:top + picture.shape[0], :picture.shape[1]] = picture
        return out

    # --------------------------------------------------------------- recording
    @property
    def recording(self) -> bool:
        return self._writer is not None

    def capture(self, step: int) -> None:
        """Call once per env step with the number of env steps done so far (1 after the first step)."""
        if self._writer is None and (step - 1) % self.every != 0:
            return  # between clips: no device access at all
        frame = self.render()
        if self.beside is not None:
            frame = np.concatenate([frame, self._beside_frame()], axis=1)
        frame = np.ascontiguousarray(frame)
        if self._writer is None:
            self._open(step)
        self._writer.send(frame)
        self._clip_frames += 1
        if self._clip_frames >= self.length:
            self._finish()

    def _open(self, step: int) -> None:
        import imageio_ffmpeg  # deferred: only recording runs need ffmpeg

        self.out_dir.mkdir(parents=True, exist_ok=True)
        self._clip_start, self._clip_frames = int(step), 0
        # Written under a temporary name and renamed when complete, so video_*.mp4 files are always whole.
        self._clip_part = self.out_dir / f"video_{self._clip_start}.mp4.part"
        self._writer = imageio_ffmpeg.write_frames(
            str(self._clip_part), (self.frame_width, self.height), fps=self.fps, codec="libx264", quality=7,
            macro_block_size=1, pix_fmt_in="rgb24", pix_fmt_out="yuv420p", output_params=["-f", "mp4"],
            ffmpeg_log_level="error",
        )
        self._writer.send(None)  # starts ffmpeg

    def _finish(self) -> Path | None:
        writer, part = self._writer, self._clip_part
        self._writer, self._clip_part = None, None
        if writer is None or part is None:
            return None
        writer.close()
        path = self.out_dir / f"video_{self._clip_start}.mp4"
        os.replace(part, path)
        self.written.append(path)
        return path

    def close(self) -> None:
        """Write out a clip in progress (shorter than ``length``) and release the renderer."""
        self._finish()
        self._release()  # runs renderer.close() once


def _ground_ids(m: mujoco.MjModel) -> set[int]:
    """The framework's ground (sim.terrain.ground_geoms: the plane, or a terrain's heightfields and border boxes) and
    any other plane or heightfield an asset brings. Not every world-body geom: a fixed base fused into the world
    (Cartpole's rail) is the robot's."""
    flat = (int(mujoco.mjtGeom.mjGEOM_PLANE), int(mujoco.mjtGeom.mjGEOM_HFIELD))
    return set(ground_geoms(m)) | {g for g in range(m.ngeom) if int(m.geom_type[g]) in flat}
