"""Reference motions for AMP: poselib ``SkeletonMotion`` files read with numpy, sampled on the device.

File format (IsaacGymEnvs' assets/amp/motions/*.npy, written by poselib's ``SkeletonMotion.to_file``, a dict saved
with ``np.save``): ``rotation.arr`` (frames, joints, 4) local joint rotations as (x, y, z, w) quaternions (the root's
is its world rotation), ``root_translation.arr`` (frames, 3), ``global_velocity.arr`` and
``global_angular_velocity.arr`` (frames, joints, 3, world frame), ``fps``, and ``skeleton_tree`` with
``node_names``, ``parent_indices.arr`` and ``local_translation.arr`` (joints, 3).

What a sample holds and how it is interpolated follows IsaacGymEnvs' ``MotionLib.get_motion_state``
(isaacgymenvs/tasks/amp/utils_amp/motion_lib.py): root position and key body positions are lerped between the two
frames around the time, root and joint rotations slerped, and the velocities are those of the earlier frame.

Joint coordinates. IsaacGymEnvs' humanoid has 3-dof joints that PhysX treats as spherical, so it writes the
exponential map of each local rotation as the three dof positions. In MuJoCo those joints are three hinges about the
body's x, y and z axes, one after the other, so a local rotation R is R = Rx(a) Ry(b) Rz(c) and the dof positions
are the intrinsic x-y-z Euler angles (a, b, c). 1-dof joints take the rotation angle times the axis component
along the hinge, wrapped to [-pi, pi], as IsaacGymEnvs does for its elbows and knees. Dof velocities are the
differences of those coordinates between consecutive frames (wrapped) over the frame time (the last frame repeats
the one before), which is what MuJoCo's hinge velocities are.

Times outside a clip are clamped to it (IsaacGymEnvs extrapolates before the first frame).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from isaacgymenvs_mw.utils.errors import ConfigError, MissingFileError
from isaacgymenvs_mw.utils.rotations import quat_mul, quat_rotate, wrap_to_pi

_FILE_KEYS = ("rotation", "root_translation", "global_velocity", "global_angular_velocity", "skeleton_tree", "fps")
AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


@dataclass(frozen=True)
class JointGroup:
    """The hinges one skeleton joint drives: ``body`` (the skeleton node and MJCF body name) and the hinge axes
    in the body frame, in order: three (x, y, z) for a ball-like joint, or one."""

    body: str
    axes: tuple[tuple[float, float, float], ...]

    @property
    def size(self) -> int:
        return len(self.axes)


@dataclass
class MotionState:
    """One sample per row: root pose and velocities (world frame, quaternions (w, x, y, z)), joint coordinates and
    velocities in the MJCF's dof order, and key body positions (world frame)."""

    root_pos: torch.Tensor      # (n, 3)
    root_rot: torch.Tensor      # (n, 4)
    dof_pos: torch.Tensor       # (n, dofs)
    root_vel: torch.Tensor      # (n, 3)
    root_ang_vel: torch.Tensor  # (n, 3)
    dof_vel: torch.Tensor       # (n, dofs)
    key_pos: torch.Tensor       # (n, keys, 3)


def load_motion_file(path: Path, key: str) -> dict:
    """The arrays of one poselib motion file as numpy (quaternions turned to (w, x, y, z))."""
    if not path.is_file():
        raise MissingFileError(f"{key}='{path.name}': no motion file at {path}")
    raw = np.load(path, allow_pickle=True)
    data = raw.item() if raw.dtype == object and raw.shape == () else None
    if not isinstance(data, dict) or any(k not in data for k in _FILE_KEYS):
        raise ConfigError(f"{key}='{path.name}' is not a poselib SkeletonMotion file (a dict with {list(_FILE_KEYS)})")
    tree = data["skeleton_tree"]
    rot = np.asarray(data["rotation"]["arr"], dtype=np.float64)[..., [3, 0, 1, 2]]
    return {
        "local_rot": rot / np.linalg.norm(rot, axis=-1, keepdims=True),
        "root_pos": np.asarray(data["root_translation"]["arr"], dtype=np.float64),
        "root_vel": np.asarray(data["global_velocity"]["arr"], dtype=np.float64)[:, 0],
        "root_ang_vel": np.asarray(data["global_angular_velocity"]["arr"], dtype=np.float64)[:, 0],
        "fps": float(data["fps"]),
        "names": list(tree["node_names"]),
        "parents": np.asarray(tree["parent_indices"]["arr"], dtype=np.int64),
        "offsets": np.asarray(tree["local_translation"]["arr"], dtype=np.float64),
    }


def forward_kinematics(local_rot: torch.Tensor, root_pos: torch.Tensor, parents: Sequence[int],
                       offsets: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """World positions and rotations (frames, joints, 3 / 4) of every skeleton joint from local rotations."""
    pos, rot = [root_pos], [local_rot[:, 0]]
    for j in range(1, local_rot.shape[1]):
        p = int(parents[j])
        if not 0 <= p < j:
            raise ConfigError(f"motion skeleton: joint {j}'s parent {p} does not come before it")
        off = offsets[j].expand(local_rot.shape[0], 3)
        pos.append(pos[p] + quat_rotate(rot[p], off))
        rot.append(quat_mul(rot[p], local_rot[:, j]))
    return torch.stack(pos, dim=1), torch.stack(rot, dim=1)


def xyz_euler(q: torch.Tensor) -> torch.Tensor:
    """(..., 3) angles (a, b, c) with q = Rx(a) Ry(b) Rz(c) for unit quaternions (..., 4) (w, x, y, z)."""
    w, x, y, z = q.unbind(-1)
    a = torch.atan2(2.0 * (w * x - y * z), 1.0 - 2.0 * (x * x + y * y))
    b = torch.asin(torch.clamp(2.0 * (x * z + w * y), -1.0, 1.0))
    c = torch.atan2(2.0 * (w * z - x * y), 1.0 - 2.0 * (y * y + z * z))
    return torch.stack((a, b, c), dim=-1)


def hinge_angle(q: torch.Tensor, axis: torch.Tensor) -> torch.Tensor:
    """(...,) rotation angle of q about ``axis`` (3,): angle x (unit rotation axis . hinge axis), in [-pi, pi]."""
    q = torch.where(q[..., :1] < 0, -q, q)
    v = q[..., 1:]
    s = torch.linalg.norm(v, dim=-1)
    angle = 2.0 * torch.atan2(s, q[..., 0])
    along = torch.sum(v * axis, dim=-1) / torch.clamp(s, min=1e-12)
    return wrap_to_pi(angle * along)


def slerp(q0: torch.Tensor, q1: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Spherical interpolation of unit quaternions (..., 4) by t (..., 1), along the shorter arc."""
    dot = torch.sum(q0 * q1, dim=-1, keepdim=True)
    q1 = torch.where(dot < 0, -q1, q1)
    dot = dot.abs().clamp(max=1.0)
    theta = torch.acos(dot)
    sin = torch.sin(theta)
    near = sin < 1e-6  # (nearly) the same rotation: a lerp is exact to rounding
    safe = torch.where(near, torch.ones_like(sin), sin)
    w0 = torch.where(near, 1.0 - t, torch.sin((1.0 - t) * theta) / safe)
    w1 = torch.where(near, t, torch.sin(t * theta) / safe)
    out = w0 * q0 + w1 * q1
    return out / torch.linalg.norm(out, dim=-1, keepdim=True)


class MotionLibrary:
    """Clips of a skeleton whose joint nodes are the MJCF's bodies; samples them in the MJCF's coordinates."""

    def __init__(self, files: Sequence[Path], joints: Sequence[JointGroup], key_bodies: Sequence[str],
                 device: str | torch.device, key: str = "env.motion_file") -> None:
        if not files:
            raise ConfigError(f"{key}: give at least one motion file")
        self.device = torch.device(device)
        self.joints = list(joints)
        self.num_dof = sum(g.size for g in self.joints)
        clips = [load_motion_file(Path(f), key) for f in files]
        names = clips[0]["names"]
        for f, clip in zip(files, clips):
            if clip["names"] != names:
                raise ConfigError(f"{key}: '{Path(f).name}' has skeleton {clip['names']}, the first file {names}")
        missing = [b for b in [g.body for g in self.joints] + list(key_bodies) if b not in names]
        if missing:
            raise ConfigError(f"{key}: the motion skeleton has no node {missing}; its nodes: {names}")
        self.node_names = names
        self._joint_nodes = [names.index(g.body) for g in self.joints]
        key_nodes = torch.tensor([names.index(b) for b in key_bodies], dtype=torch.long)
        parts: dict[str, list[torch.Tensor]] = {k: [] for k in ("root_pos", "root_rot", "local_rot", "root_vel",
                                                               "root_ang_vel", "dof_vel", "key_pos", "body_pos")}
        starts, frames, dts = [], [], []
        for f, clip in zip(files, clips):
            if clip["local_rot"].shape[0] < 2 or not clip["fps"] > 0:
                raise ConfigError(f"{key}: '{Path(f).name}' needs at least 2 frames and fps > 0")
            local_rot = torch.tensor(clip["local_rot"], dtype=torch.float64)
            root_pos = torch.tensor(clip["root_pos"], dtype=torch.float64)
            body_pos, body_rot = forward_kinematics(local_rot, root_pos, clip["parents"],
                                                    torch.tensor(clip["offsets"], dtype=torch.float64))
            dt = 1.0 / clip["fps"]
            dof = self.rotations_to_dof(local_rot)
            vel = wrap_to_pi(dof[1:] - dof[:-1]) / dt
            starts.append(sum(frames))
            frames.append(local_rot.shape[0])
            dts.append(dt)
            for name, value in (("root_pos", root_pos), ("root_rot", body_rot[:, 0]), ("local_rot", local_rot),
                                ("root_vel", torch.tensor(clip["root_vel"])),
                                ("root_ang_vel", torch.tensor(clip["root_ang_vel"])),
                                ("dof_vel", torch.cat((vel, vel[-1:]), dim=0)), ("key_pos", body_pos[:, key_nodes]),
                                ("body_pos", body_pos)):
                parts[name].append(value)
        dev = self.device
        for name, values in parts.items():
            setattr(self, "_" + name, torch.cat(values).to(dev, torch.float32))
        self._start = torch.tensor(starts, device=dev, dtype=torch.long)
        self._frames = torch.tensor(frames, device=dev, dtype=torch.long)
        self._dt = torch.tensor(dts, device=dev, dtype=torch.float32)
        self.lengths = (self._frames - 1).float() * self._dt  # (motions,) seconds from the first to the last frame
        self._weights = torch.ones(len(clips), device=dev)
        self.fps = [c["fps"] for c in clips]

    @property
    def num_motions(self) -> int:
        return int(self._start.shape[0])

    def frame(self, motion: int, index: int) -> dict[str, torch.Tensor]:
        """One stored frame (what the file says, turned into the MJCF's coordinates): for tests and tools."""
        i = int(self._start[motion]) + index
        return {"root_pos": self._root_pos[i], "root_rot": self._root_rot[i], "local_rot": self._local_rot[i],
                "key_pos": self._key_pos[i], "body_pos": self._body_pos[i], "dof_vel": self._dof_vel[i]}

    def rotations_to_dof(self, local_rot: torch.Tensor) -> torch.Tensor:
        """(n, dofs) joint coordinates of skeleton local rotations (n, joints, 4) (module docstring)."""
        cols = []
        for group, node in zip(self.joints, self._joint_nodes):
            q = local_rot[:, node]
            if group.axes == AXES:
                cols.append(xyz_euler(q))
            elif group.size == 1:
                axis = torch.tensor(group.axes[0], dtype=q.dtype, device=q.device)
                cols.append(hinge_angle(q, axis).unsqueeze(-1))
            else:
                raise ConfigError(f"motion library: joint '{group.body}' has hinges {group.axes}; only one hinge or "
                                  "three about x, y, z in that order are read from a motion")
        return torch.cat(cols, dim=-1)

    def sample_motions(self, n: int) -> torch.Tensor:
        """(n,) motion indices drawn by weight (equal weights)."""
        return torch.multinomial(self._weights, n, replacement=True)

    def sample_times(self, motion_ids: torch.Tensor, truncate: float = 0.0) -> torch.Tensor:
        """(n,) times drawn uniformly over each motion (less ``truncate`` seconds at the end)."""
        length = torch.clamp(self.lengths[motion_ids] - truncate, min=0.0)
        return torch.rand(motion_ids.shape, device=self.device) * length

    def state(self, motion_ids: torch.Tensor, times: torch.Tensor) -> MotionState:
        """The motions' states at ``times`` (s), interpolated between the frames around them."""
        dt = self._dt[motion_ids]
        last = self._frames[motion_ids] - 1
        times = torch.minimum(torch.clamp(times, min=0.0), self.lengths[motion_ids])
        # a frame's own time lands on that frame, not a rounding below it on the one before
        i0 = torch.minimum(torch.floor(times / dt + 1e-4).long(), last)
        i1 = torch.minimum(i0 + 1, last)
        blend = torch.clamp((times - i0.float() * dt) / dt, 0.0, 1.0).unsqueeze(-1)
        f0, f1 = self._start[motion_ids] + i0, self._start[motion_ids] + i1
        local_rot = slerp(self._local_rot[f0], self._local_rot[f1], blend.unsqueeze(-1))
        return MotionState(
            root_pos=(1.0 - blend) * self._root_pos[f0] + blend * self._root_pos[f1],
            root_rot=slerp(self._root_rot[f0], self._root_rot[f1], blend),
            dof_pos=self.rotations_to_dof(local_rot),
            root_vel=self._root_vel[f0],
            root_ang_vel=self._root_ang_vel[f0],
            dof_vel=self._dof_vel[f0],
            key_pos=(1.0 - blend.unsqueeze(-1)) * self._key_pos[f0] + blend.unsqueeze(-1) * self._key_pos[f1],
        )


def motion_files(value: object, folder: Path, key: str = "env.motion_file") -> list[Path]:
    """``env.motion_file``: a file name (or a list of them) under ``folder`` (assets/amp/motions), or paths."""
    names = [value] if isinstance(value, str) else list(value) if isinstance(value, (list, tuple)) else None
    if not names or not all(isinstance(n, str) and n for n in names):
        raise ConfigError(f"{key}={value!r} is invalid: give a motion file name (e.g. amp_humanoid_run.npy) or a list")
    return [Path(n) if Path(n).is_absolute() else folder / n for n in names]

