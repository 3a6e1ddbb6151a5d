"""Observation history: the policy (and/or critic) input stacked over the last ``length`` env steps.

Configured per task under ``env.history`` (docs/config.md):

    env:
      history:
        policy: {length: 3, terms: [dof_pos, dof_vel, actions]}   # terms: omitted = the whole vector
        critic: {length: 2}
        camera: {length: 3}                                     # image frames (the "camera" group)

The task still computes one frame (``numObservations`` / ``numStates`` columns, the YAML sizes). What the learner
sees is that frame followed by the selected columns of the ``length - 1`` frames before it, newest first:

    [ obs_t (all columns) | sel(obs_{t-1}) | sel(obs_{t-2}) | ... | sel(obs_{t-length+1}) ]

so its size is ``n + (length - 1) * len(sel)``, and the first ``n`` columns are exactly the observation without
history. An env whose ``reset_buf`` is set returned the first frame of a new episode: all its past frames are
filled with that frame (nothing from the previous episode leaks in). The frames live on the device in a shift
buffer, updated with whole-tensor ops only (no host syncs, capturable, compilable).

Images (the ``camera`` group, (C, H, W) uint8 frames) are stacked the same way along channels (``ImageStack``): the
stacked input is (C + (length - 1) * C_sel, H, W), the current frame's channels first, then the selected terms'
channels of each past frame, newest first. Image stacks are large (a 64x64 RGB stack of 3 frames is 36 KB per env),
so they are not shifted in place and copied out: two stack buffers take turns, each step writing the new stack into
one from the other (the new frame, and the older frames one slot back), and the learner gets that buffer itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from isaacgymenvs_mw.tasks.base.observation_terms import ObsLayout
from isaacgymenvs_mw.utils.config import whole_number
from isaacgymenvs_mw.utils.errors import ConfigError

GROUPS = ("policy", "critic", "camera")


@dataclass(frozen=True)
class HistorySpec:
    """One group's ``env.history.<group>`` section, checked."""

    key: str                       # "env.history.policy", for error messages
    length: int = 1                # frames the learner sees; 1 = no history
    terms: tuple[str, ...] | None = None  # None: every column


def parse_history(env: dict) -> dict[str, HistorySpec]:
    """``env.history`` as {group: HistorySpec}; groups with length 1 are left out. Fails naming the key."""
    section = env.get("history")
    if section in (None, {}):
        return {}
    if not isinstance(section, dict):
        raise ConfigError(f"env.history={section!r} is invalid: give a mapping with keys {list(GROUPS)}")
    unknown = [k for k in section if k not in GROUPS]
    if unknown:
        raise ConfigError(f"env.history: unknown group(s) {unknown}; valid groups: {list(GROUPS)}")
    out = {}
    for group, cfg in section.items():
        key = f"env.history.{group}"
        if cfg is None:
            continue
        if not isinstance(cfg, dict):
            raise ConfigError(f"{key}={cfg!r} is invalid: give a mapping with keys ['length', 'terms']")
        bad = [k for k in cfg if k not in ("length", "terms")]
        if bad:
            raise ConfigError(f"{key}: unknown key(s) {bad}; valid keys: ['length', 'terms']")
        length = whole_number(cfg.get("length", 1), f"{key}.length", 1)
        terms = cfg.get("terms")
        if terms is not None:
            if isinstance(terms, str) or not all(isinstance(t, str) for t in terms) or len(terms) == 0:
                raise ConfigError(f"{key}.terms={terms!r} is invalid: give a non-empty list of observation term "
                                 "names, or leave it out to stack the whole vector")
            terms = tuple(terms)
        if length > 1:
            out[group] = HistorySpec(key, length, terms)
    return out


class ObsHistory:
    """The last ``length`` frames of the selected columns of an observation vector, for every env.

    Args:
        spec: the checked YAML section.
        size: columns of one frame (``numObservations`` or ``numStates``).
        layout: the frame's named terms; required when ``spec.terms`` selects some.
        num_envs, device: batch and device of the buffers.
        dtype: the frames' dtype (uint8 for images).
    """

    def __init__(self, spec: HistorySpec, size: int, layout: ObsLayout | None, num_envs: int,
                 device: torch.device | str, dtype: torch.dtype = torch.float32) -> None:
        self.spec = spec
        self.length = spec.length
        self.frame_size = int(size)
        if spec.terms is None:
            columns = torch.arange(self.frame_size)
        elif layout is None:
            raise ConfigError(f"{spec.key}.terms={list(spec.terms)}: this task declares no observation terms "
                             "(observation_terms()/state_terms()), so only the whole vector can be stacked; "
                             f"leave out {spec.key}.terms")
        else:
            columns = layout.columns(list(spec.terms), f"{spec.key}.terms")
        self.columns = columns.to(device)
        self.selected = int(self.columns.numel())
        self.size = self.frame_size + (self.length - 1) * self.selected
        # frames[:, 0] is the newest frame's selection, frames[:, k] the one k steps before.
        self.frames = torch.zeros(num_envs, self.length, self.selected, device=device, dtype=dtype)
        self.out = torch.zeros(num_envs, self.size, device=device, dtype=dtype)

    def describe(self) -> dict:
        """What an exported policy needs to rebuild the stacked input on a robot."""
        return {"length": self.length, "terms": list(self.spec.terms) if self.spec.terms else None,
                "columns": self.columns.tolist(), "frame_size": self.frame_size, "size": self.size,
                "order": "current frame (all columns), then the selected columns of past frames, newest first"}

    def push(self, frame: torch.Tensor, new_episode: torch.Tensor) -> torch.Tensor:
        """Add this step's frame; envs flagged in ``new_episode`` forget their past. Returns the stacked input."""
        sel = frame.index_select(1, self.columns)
        # Shift older frames back by one; the clone keeps the overlapping copy well defined.
        self.frames[:, 1:] = self.frames[:, :-1].clone()
        self.frames[:, 0] = sel
        self.frames.copy_(torch.where(new_episode.view(-1, 1, 1), sel.unsqueeze(1), self.frames))
        return self._stack(frame)

    def reset(self, frame: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Fill every past frame of the masked envs with ``frame`` (no shift). Returns the stacked input."""
        sel = frame.index_select(1, self.columns)
        self.frames.copy_(torch.where(mask.view(-1, 1, 1), sel.unsqueeze(1), self.frames))
        return self._stack(frame)

    def _stack(self, frame: torch.Tensor) -> torch.Tensor:
        self.out[:, :self.frame_size] = frame
        self.out[:, self.frame_size:] = self.frames[:, 1:].reshape(self.out.shape[0], -1)
        return self.out


class ImageStack:
    """The "camera" group: each env's newest frame of the image terms and, with ``env.history.camera``, the frames
    before it, (num_envs, C + (length - 1) * C_sel, H, W) uint8 on the device.

    Two buffers take turns: env step ``k`` (0-based) writes buffer ``k % 2`` from buffer ``(k - 1) % 2``, so a step
    moves each byte of the stack about twice (read the older frames, write them one slot back, plus the new frame)
    and hands its buffer to the learner without a copy. That buffer is rewritten two steps later: a learner that
    keeps an observation longer than one step copies it (rsl-rl-lib copies each into its rollout storage at the
    next step). Which buffer a step writes is a pure function of the step number, so a captured graph per buffer
    replays with no host-side state to update.

    Args:
        group: the image terms (their cameras, channels and size).
        spec: ``env.history.camera``, or None: the newest frame only.
        num_envs, device: batch and device of the buffers.
    """

    def __init__(self, group, spec: HistorySpec | None, num_envs: int, device: torch.device | str) -> None:
        self.group = group
        self.spec = spec
        self.length = spec.length if spec is not None else 1
        self.channels, height, width = group.shape
        if spec is None or spec.terms is None:
            self.selected = torch.arange(self.channels)
        else:  # whole terms: their channel blocks (the layout checks the names and counts H * W columns per channel)
            columns = group.layout.columns(list(spec.terms), f"{spec.key}.terms")
            self.selected = torch.unique(columns // (height * width))
        self.all_channels = self.selected.numel() == self.channels  # past frames keep every channel: one slice
        self.selected = self.selected.to(device)
        past = (self.length - 1) * int(self.selected.numel())
        self.shape = (self.channels + past, height, width)
        self.buffers = tuple(torch.zeros((num_envs, *self.shape), dtype=torch.uint8, device=device)
                             for _ in range(2))

    def newest(self, steps_taken: int) -> torch.Tensor:
        """The stack after ``steps_taken`` env steps (before the first: what ``restart`` wrote)."""
        return self.buffers[(steps_taken - 1) % 2]

    def frame(self, steps_taken: int) -> torch.Tensor:
        """The newest frame alone, (num_envs, C, H, W), after ``steps_taken`` env steps."""
        return self.newest(steps_taken)[:, :self.channels]

    def push(self, new_episode: torch.Tensor, step: int) -> torch.Tensor:
        """Env step ``step``: the cameras' images become the newest frame, the older frames move back one slot;
        envs flagged in ``new_episode`` forget their past (every past frame is the new one). Returns the stack."""
        into, older = self.buffers[step % 2], self.buffers[(step - 1) % 2]
        frame = self.group.compute(into[:, :self.channels])
        if self.length > 1:
            self._fill_past(into, frame, new_episode, older)
        return into

    def restart(self, mask: torch.Tensor, steps_taken: int) -> torch.Tensor:
        """The cameras' images become the newest frame, in place (no shift); the past frames of the masked envs
        become copies of it (their episode starts). Returns the stack."""
        stack = self.newest(steps_taken)
        frame = self.group.compute(stack[:, :self.channels])
        if self.length > 1:
            self._fill_past(stack, frame, mask, None)
        return stack

    def _fill_past(self, into: torch.Tensor, frame: torch.Tensor, forget: torch.Tensor,
                   older: torch.Tensor | None) -> None:
        """``into``'s past frames: ``older``'s frames one slot back (``older`` None: ``into``'s own, unshifted),
        and the selected channels of ``frame`` in every slot of the envs in ``forget``."""
        n, c = frame.shape[0], self.channels
        h, w = self.shape[1:]
        s = int(self.selected.numel())
        past = into[:, c:].view(n, self.length - 1, s, h, w)
        current = frame if self.all_channels else frame.index_select(1, self.selected)
        forget = forget.view(n, 1, 1, 1, 1)
        if older is None:
            torch.where(forget, current.unsqueeze(1), past, out=past)  # elementwise in place: each byte reads itself
        elif self.all_channels:
            torch.where(forget, current.unsqueeze(1), older[:, :-c].view_as(past), out=past)
        else:  # the previous frame's selected channels, then its past frames but the oldest
            previous = older[:, :c].index_select(1, self.selected).unsqueeze(1)
            torch.where(forget, current.unsqueeze(1), previous, out=past[:, :1])
            if self.length > 2:
                torch.where(forget, current.unsqueeze(1), older[:, c:c + (self.length - 2) * s].view_as(past[:, 1:]),
                            out=past[:, 1:])

    def describe(self) -> dict:
        """What an exported policy needs to rebuild the stacked input on a robot."""
        return {"length": self.length, "terms": list(self.spec.terms) if self.spec and self.spec.terms else None,
                "channels": self.selected.tolist(), "frame_channels": self.channels, "size": self.shape[0],
                "order": "current frame (all channels), then the selected channels of past frames, newest first"}
