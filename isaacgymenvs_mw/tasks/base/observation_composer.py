"""The observation groups of a VecTask, as one object VecTask composes (``VecTask.observations``): the policy
observation and the critic state built from the terms a task declares (``observation_terms()`` / ``state_terms()``),
with their sizes, buffers, spaces and history; the image observation (the "camera" group, (num_envs, C, H, W) uint8,
from ``image_terms()``) with its frame stack; what a step and a reset hand to the learner; and the description an
exported policy carries. It knows nothing of the task: VecTask gives it the sizes, the terms and the episode starts.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Callable

import gymnasium as gym
import numpy as np
import torch

from isaacgymenvs_mw.tasks.base.history import HistorySpec, ImageStack, ObsHistory
from isaacgymenvs_mw.tasks.base.observation_terms import ImageGroup, ImageTerm, ObsLayout, ObsTerm
from isaacgymenvs_mw.utils.errors import ConfigError

if TYPE_CHECKING:  # the simulator's sensor registry, whose cameras the image terms read
    from isaacgymenvs_mw.sim.sensor_registry import SensorRegistry


def _box(size: int) -> gym.spaces.Box:
    return gym.spaces.Box(-np.inf, np.inf, shape=(size,), dtype=np.float32)


def _finite(x: float) -> float | None:  # JSON has no inf: "no clipping" is null
    return x if math.isfinite(x) else None


class Observations:
    """The policy, critic and camera groups of one task.

    Args:
        task: the task's class name, for messages.
        num_envs, device, rl_device: the batch, where the buffers live and where the learner reads them.
        num_obs, num_states: ``env.numObservations`` (0: derived from the terms) and ``env.numStates`` (None: absent;
            0 turns the critic state off).
        clip: ``env.clipObservations``.
        history: ``env.history``, parsed.
        term_noise: gives the policy layout the randomisation layer's per-term noise.
        image_terms: the task's image terms (None: no image observation).
        sensors: the simulator's sensor registry (``sim.sensors``), whose cameras the image terms read.
        sensor_terms: the terms of ``env.observeSensors`` (``observations.sensor_terms``): appended to the policy
            terms, and to the critic's state terms where these do not hold them already (noiseless there).
    """

    def __init__(self, task: str, num_envs: int, device: str, rl_device: str, num_obs: int, num_states: int | None,
                 clip: float, history: dict[str, HistorySpec], term_noise: Callable[[ObsLayout], ObsLayout],
                 image_terms: list[ImageTerm] | None, sensors: SensorRegistry,
                 sensor_terms: list[ObsTerm] = ()) -> None:
        self.task, self.num_envs, self.device, self.rl_device = task, num_envs, device, rl_device
        self.clip, self.history, self._term_noise = clip, history, term_noise
        self.sensor_terms = list(sensor_terms)
        self._yaml_num_obs, self._yaml_num_states = num_obs, num_states
        self.num_obs, self.num_states = num_obs, num_states or 0
        self.obs_layout: ObsLayout | None = None
        self.state_layout: ObsLayout | None = None
        self.obs_history: ObsHistory | None = None
        self.state_history: ObsHistory | None = None
        self.built = False
        self.images = ImageGroup(image_terms, sensors) if image_terms else None
        if "camera" in history and self.images is None:
            raise ConfigError("env.history.camera needs image observation terms; this task declares none "
                              "(image_terms())")
        # The "camera" group: the newest frame and env.history.camera's past frames.
        self.image_stack = None if self.images is None else ImageStack(self.images, history.get("camera"), num_envs,
                                                                      device)
        self._allocate()

    @property
    def wants_state_terms(self) -> bool:
        """False where ``numStates: 0`` turns the critic state off (the task's state terms are then not asked for)."""
        return self._yaml_num_states != 0

    def build(self, obs_terms: list[ObsTerm] | None, state_terms: list[ObsTerm] | None) -> None:
        """Derive the layouts and sizes from the declared terms (a YAML size must agree), then the buffers, spaces
        and history of those sizes (before the first step, so before any capture). The observed sensors' terms
        (``sensor_terms``) come after the task's own."""
        if self.sensor_terms:
            if obs_terms is None:
                raise ConfigError(f"env.observeSensors={[t.name for t in self.sensor_terms]}: this task fills its "
                                  "observation itself (no observation_terms()); observe the sensors there, or set "
                                  "env.observeSensors: {}")
            obs_terms = [*obs_terms, *self.sensor_terms]
            if state_terms:
                held = {t.name for t in state_terms}
                state_terms = [*state_terms, *(t for t in self.sensor_terms if t.name not in held)]
        if obs_terms is not None:
            self.obs_layout = self._term_noise(ObsLayout(obs_terms))
            if self._yaml_num_obs:
                self.obs_layout.check(self._yaml_num_obs, "env.numObservations")
            self.num_obs = self.obs_layout.size
        if state_terms and self.wants_state_terms:  # [] declares no state, as None does
            self.state_layout = ObsLayout(state_terms)
            if self._yaml_num_states:
                self.state_layout.check(self._yaml_num_states, "env.numStates")
            self.num_states = self.state_layout.size
        if "critic" in self.history and self.num_states == 0:
            raise ConfigError("env.history.critic needs env.numStates > 0; with numStates 0 the critic sees the "
                              "policy observation, history included (env.history.policy)")
        if self.obs_buf.shape[1] != self.num_obs or self.states_buf.shape[1] != self.num_states:
            self._allocate()
        n, dev = self.num_envs, self.device
        if "policy" in self.history:  # the spaces (and so the networks) take the stacked sizes
            self.obs_history = ObsHistory(self.history["policy"], self.num_obs, self.obs_layout, n, dev)
            self.obs_space = _box(self.obs_history.size)
        if "critic" in self.history:
            self.state_history = ObsHistory(self.history["critic"], self.num_states, self.state_layout, n, dev)
            self.state_space = _box(self.state_history.size)
        self.built = True

    def _allocate(self) -> None:
        n, dev = self.num_envs, self.device
        self.obs_buf = torch.zeros((n, self.num_obs), device=dev, dtype=torch.float)
        self.states_buf = torch.zeros((n, self.num_states), device=dev, dtype=torch.float)
        # Step outputs live in fixed buffers so that a captured step graph can write them.
        self.obs_out = torch.zeros_like(self.obs_buf)
        self.states_out = torch.zeros_like(self.states_buf)
        self.obs_space, self.state_space = _box(self.num_obs), _box(self.num_states)

    # ------------------------------------------------------------------ computing
    def compute(self) -> None:
        """Fill ``obs_buf`` (and ``states_buf``) from the layouts, in term order: each term's ``compute()`` times its
        scale. A term both groups observe is computed once."""
        values: dict[str, torch.Tensor] = {}

        def column_values(layout: ObsLayout) -> torch.Tensor:
            parts = []
            for term in layout.terms:
                if term.name not in values:
                    values[term.name] = term.compute()
                parts.append(values[term.name] * term.scale)
            return torch.cat(parts, dim=-1)

        self.obs_buf[:] = column_values(self.obs_layout)
        if self.state_layout is not None:
            self.states_buf[:] = column_values(self.state_layout)

    def compute_checked(self, compute: Callable[[], None]) -> None:
        """Run the task's ``compute``, failing clearly when numObservations / numStates disagree with what it
        writes."""
        self.obs_buf.fill_(math.nan)
        self.states_buf.fill_(math.nan)
        try:
            compute()
        except RuntimeError as err:
            if "size" in str(err) or "shape" in str(err):
                raise ConfigError(
                    f"{self.task}: the observation it computes does not fit env.numObservations="
                    f"{self.num_obs} / env.numStates={self.num_states} ({err})"
                ) from err
            raise
        for key, buf, size in (("numObservations", self.obs_buf, self.num_obs),
                               ("numStates", self.states_buf, self.num_states)):
            written = (~torch.isnan(buf)).any(dim=0)
            if size and not bool(written.all()):
                raise ConfigError(
                    f"{self.task}: env.{key}={size} but the task wrote only {int(written.sum())} "
                    f"columns; set env.{key} to the size the task computes"
                )

    def finish_step(self, new_episode: torch.Tensor) -> torch.Tensor:
        """The step's outputs from the buffers: NaN/inf to 0, clamped, pushed into the history (an env of
        ``new_episode`` returned its new episode's first frame). Returns the envs whose observation was not finite.
        Device work only (captured on CUDA)."""
        bad = ~torch.isfinite(self.obs_buf).all(dim=-1)
        torch.clamp(torch.nan_to_num(self.obs_buf, nan=0.0, posinf=0.0, neginf=0.0), -self.clip, self.clip,
                    out=self.obs_out)
        if self.num_states > 0:
            bad |= ~torch.isfinite(self.states_buf).all(dim=-1)
            torch.clamp(torch.nan_to_num(self.states_buf, nan=0.0, posinf=0.0, neginf=0.0), -self.clip, self.clip,
                        out=self.states_out)
        if self.obs_history is not None:
            self.obs_history.push(self.obs_out, new_episode)
        if self.state_history is not None:
            self.state_history.push(self.states_out, new_episode)
        return bad

    def observe_images(self, new_episode: torch.Tensor, step: int) -> None:
        """The "camera" group of env step ``step`` (0-based) from the cameras' current images (torch; captured as a
        graph per stack buffer on CUDA)."""
        self.image_stack.push(new_episode, step)

    # ---------------------------------------------------------- for the learner
    def step_outputs(self, out: dict[str, torch.Tensor], steps: int) -> dict[str, torch.Tensor]:
        """The observation ``steps`` env steps in, into ``out`` on the learner's device. The next step rewrites the
        output buffers in place while the learner still holds this observation: the flat groups are copied."""
        out["obs"] = (self.obs_out if self.obs_history is None else self.obs_history.out).to(self.rl_device,
                                                                                          copy=True)
        if self.num_states > 0:
            states = self.states_out if self.state_history is None else self.state_history.out
            out["states"] = states.to(self.rl_device, copy=True)
        if self.images is not None:  # no copy: the buffer this step wrote stays as it is for one more step
            out["camera"] = self.image_stack.newest(steps).to(self.rl_device)
        return out

    def reset_outputs(self, out: dict[str, torch.Tensor], new_episode: torch.Tensor,
                      steps: int) -> dict[str, torch.Tensor]:
        """The current observations, clamped, into ``out``; the ``new_episode`` envs' past frames are refilled."""
        obs = torch.clamp(self.obs_buf, -self.clip, self.clip)
        if self.obs_history is not None:
            obs = self.obs_history.reset(obs, new_episode)
        out["obs"] = obs.to(self.rl_device, copy=True)
        if self.num_states > 0:
            states = torch.clamp(self.states_buf, -self.clip, self.clip)
            if self.state_history is not None:
                states = self.state_history.reset(states, new_episode)
            out["states"] = states.to(self.rl_device, copy=True)
        if self.images is not None:
            self.image_stack.restart(new_episode, steps)
            out["camera"] = self.image_stack.newest(steps).to(self.rl_device)
        return out

    def get_state(self) -> torch.Tensor:
        """The critic's input as the last step returned it (stacked when ``env.history.critic`` is set)."""
        if self.state_history is not None:
            return self.state_history.out.to(self.rl_device, copy=True)
        return torch.clamp(self.states_buf, -self.clip, self.clip).to(self.rl_device)

    @property
    def image_shape(self) -> tuple[int, int, int] | None:
        """(C, H, W) of the "camera" group as the learner sees it (frames stacked); None without image terms."""
        return None if self.image_stack is None else self.image_stack.shape

    def camera_picture(self, steps: int, world: int = 0) -> torch.Tensor:
        """World ``world``'s newest image observation as an (H, W * terms, 3) uint8 RGB picture (terms side by
        side, depth as grey): what videos show beside the usual view."""
        return self.images.picture(self.image_stack.frame(steps), world)

    def describe(self) -> dict[str, Any]:
        """The groups as an exported policy needs them: clipping, each group's terms, sizes and history."""

        def group(layout: ObsLayout | None, size: int, history: ObsHistory | None) -> dict[str, Any]:
            return {"size": size if history is None else history.size, "frame_size": size,
                    "terms": layout.describe() if layout is not None else None,
                    "history": history.describe() if history is not None else {"length": 1}}

        info: dict[str, Any] = {"clip_observations": _finite(self.clip),
                                "observation": group(self.obs_layout, self.num_obs, self.obs_history)}
        if self.num_states > 0:
            info["state"] = group(self.state_layout, self.num_states, self.state_history)
        if self.images is not None:
            info["camera"] = {"shape": list(self.image_shape), "frame_shape": list(self.images.shape),
                              "dtype": "uint8", "terms": self.images.describe(),
                              "history": self.image_stack.describe() if self.image_stack.length > 1
                              else {"length": 1}}
        return info
