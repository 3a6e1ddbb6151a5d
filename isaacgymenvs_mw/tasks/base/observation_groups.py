"""The observation groups of a VecTask: the policy observation and the critic state, built from the terms a task
declares (``observation_terms()`` / ``state_terms()``), with their sizes, buffers, spaces, history and the
metadata an exported policy carries; and the image observation (``image_terms()``: camera images, the "camera"
group, (num_envs, C, H, W) uint8). VecTask inherits it; a task only declares terms."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from isaacgymenvs_mw.tasks.base.history import ImageStack, ObsHistory
from isaacgymenvs_mw.tasks.base.observations import ImageGroup, ImageTerm, ObsLayout, ObsTerm
from isaacgymenvs_mw.utils.errors import ConfigError


class ObservationGroups:
    """Mixed into VecTask: everything between a task's declared terms and the tensors a step returns."""

    def observation_terms(self) -> list[ObsTerm] | None:
        """The policy observation as named terms (``ObsTerm(name, size, scale, noise, compute=...)``), in column
        order; VecTask's ``compute_observations`` builds ``obs_buf`` from them and ``numObservations`` is their
        total. None: the task declares no layout, fills ``obs_buf`` itself and gives ``numObservations``."""
        return None

    def state_terms(self) -> list[ObsTerm] | None:
        """The privileged critic state as named terms; ``numStates`` is their total (``numStates: 0`` in the YAML
        turns the critic state off). None: no critic state, or one the task fills itself (``numStates`` > 0)."""
        return None

    def image_terms(self) -> list[ImageTerm] | None:
        """The image observation as named camera images (``ImageTerm(name, camera, output)``), stacked along
        channels into the "camera" group, (num_envs, C, H, W) uint8; the cameras are ``env.cameras`` entries and are
        rendered after each step's resets (every ``env.renderInterval`` steps). None: no image observation."""
        return None

    def build_observation_layouts(self) -> None:
        """Derive ``obs_layout`` / ``state_layout`` and the sizes from the declared terms (a YAML size must agree),
        then the buffers, spaces and history of those sizes.

        ``reset()`` calls it; a task whose terms depend on its own ``__init__`` calls it at the end of that, so that
        a wrong size fails at construction.
        """
        terms = self.observation_terms()
        if terms is not None:
            self.obs_layout = self.randomizer.with_term_noise(ObsLayout(terms))
            if self._yaml_num_obs:
                self.obs_layout.check(self._yaml_num_obs, "env.numObservations")
            self.num_observations = self.obs_layout.size
        terms = self.state_terms() if self._yaml_num_states != 0 else None
        if terms is not None:
            self.state_layout = ObsLayout(terms)
            if self._yaml_num_states:
                self.state_layout.check(self._yaml_num_states, "env.numStates")
            self.num_states = self.state_layout.size
        if "critic" in self.history_specs and self.num_states == 0:
            raise ConfigError("env.history.critic needs env.numStates > 0; with numStates 0 the critic sees the "
                             "policy observation, history included (env.history.policy)")
        terms = self.image_terms()
        if terms and self.images is None:
            self.images = ImageGroup(terms, self.sim)
            # Each step then renders after the resets and reads the images (VecTask.step).
            self.execution.sensors = (self._render_cameras, self._observe_step_images)
        if "camera" in self.history_specs and self.images is None:
            raise ConfigError("env.history.camera needs image observation terms; this task declares none "
                              "(image_terms())")
        if self.obs_buf.shape[1] != self.num_observations or self.states_buf.shape[1] != self.num_states:
            self._resize_observation_buffers()
        self._layouts_built = True
        self._build_history()

    def _resize_observation_buffers(self) -> None:
        """Observation buffers and spaces of the derived sizes (before the first step, so before any capture)."""
        n, dev = self.num_envs, self.device
        self.obs_buf = torch.zeros((n, self.num_observations), device=dev, dtype=torch.float)
        self.states_buf = torch.zeros((n, self.num_states), device=dev, dtype=torch.float)
        self._obs_out = torch.zeros_like(self.obs_buf)
        self._states_out = torch.zeros_like(self.states_buf)
        self.obs_space = gym.spaces.Box(-np.inf, np.inf, shape=(self.num_observations,), dtype=np.float32)
        self.state_space = gym.spaces.Box(-np.inf, np.inf, shape=(self.num_states,), dtype=np.float32)

    def _build_history(self) -> None:
        """``env.history``: stacked policy/critic inputs; the spaces (and so the networks) take the stacked sizes."""
        n, dev = self.num_envs, self.device
        spec = self.history_specs.get("policy")
        if spec is not None and self.obs_history is None:
            self.obs_history = ObsHistory(spec, self.num_obs, self.obs_layout, n, dev)
            self.obs_space = gym.spaces.Box(-np.inf, np.inf, shape=(self.obs_history.size,), dtype=np.float32)
        spec = self.history_specs.get("critic")
        if spec is not None and self.state_history is None:
            self.state_history = ObsHistory(spec, self.num_states, self.state_layout, n, dev)
            self.state_space = gym.spaces.Box(-np.inf, np.inf, shape=(self.state_history.size,), dtype=np.float32)
        if self.images is not None and self.image_stack is None:
            self.image_stack = ImageStack(self.images, self.history_specs.get("camera"), n, dev)

    @property
    def image_shape(self) -> tuple[int, int, int] | None:
        """(C, H, W) of the "camera" group as the learner sees it (frames stacked); None without image terms."""
        return None if self.image_stack is None else self.image_stack.shape

    def camera_picture(self, world: int = 0) -> torch.Tensor:
        """World ``world``'s newest image observation as an (H, W * terms, 3) uint8 RGB picture (terms side by
        side, depth as grey): what videos show beside the usual view."""
        return self.images.picture(self.image_stack.frame(self.execution.steps), world)

    def compute_observations(self) -> None:
        """Fill ``obs_buf`` (and ``states_buf``) from the layouts, in term order: each term's ``compute()`` times its
        scale. A term both groups observe is computed once. A task without a layout overrides this."""
        if self.obs_layout is None:
            raise NotImplementedError(self.missing_hook_message("compute_observations"))
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

    def deployment_info(self) -> dict[str, Any]:
        """What a runtime needs to feed an exported policy and apply its actions (``learning/export.py`` adds the
        versions). Tasks with joints add their joint names, default pose, action scale and PD gains."""
        if not self._layouts_built:
            self.build_observation_layouts()

        def finite(x: float) -> float | None:  # JSON has no inf: "no clipping" is null
            return x if math.isfinite(x) else None

        def group(layout: ObsLayout | None, size: int, history: ObsHistory | None) -> dict[str, Any]:
            return {"size": size if history is None else history.size, "frame_size": size,
                    "terms": layout.describe() if layout is not None else None,
                    "history": history.describe() if history is not None else {"length": 1}}

        info: dict[str, Any] = {
            "task": type(self).__name__,
            "control_dt": self.control_dt,
            "physics_dt": self.dt,
            "decimation": self.control_freq_inv,
            "num_actions": self.num_actions,
            "clip_actions": finite(self.clip_actions),
            "clip_observations": finite(self.clip_obs),
            "observation": group(self.obs_layout, self.num_obs, self.obs_history),
        }
        if self.num_states > 0:
            info["state"] = group(self.state_layout, self.num_states, self.state_history)
        if self.images is not None:
            info["camera"] = {"shape": list(self.image_shape), "frame_shape": list(self.images.shape),
                              "dtype": "uint8", "terms": self.images.describe(),
                              "history": self.image_stack.describe() if self.image_stack.length > 1
                              else {"length": 1}}
        return info

    def get_state(self) -> torch.Tensor:
        """The critic's input as the last step returned it (stacked when ``env.history.critic`` is set)."""
        if self.state_history is not None:
            return self.state_history.out.to(self.rl_device, copy=True)
        return torch.clamp(self.states_buf, -self.clip_obs, self.clip_obs).to(self.rl_device)

    def _clamped_obs_dict(self, new_episode: torch.Tensor) -> dict[str, torch.Tensor]:
        """The current observations, clamped; with ``env.history`` the ``new_episode`` envs' past is refilled."""
        obs = torch.clamp(self.obs_buf, -self.clip_obs, self.clip_obs)
        if self.obs_history is not None:
            obs = self.obs_history.reset(obs, new_episode)
        self.obs_dict["obs"] = obs.to(self.rl_device, copy=True)
        if self.num_states > 0:
            states = torch.clamp(self.states_buf, -self.clip_obs, self.clip_obs)
            if self.state_history is not None:
                states = self.state_history.reset(states, new_episode)
            self.obs_dict["states"] = states.to(self.rl_device, copy=True)
        if self.images is not None:
            self.sim.render_cameras()
            self.image_stack.restart(new_episode, self.execution.steps)
            self.obs_dict["camera"] = self.image_stack.newest(self.execution.steps).to(self.rl_device)
        return self.obs_dict

    def _compute_checked_observations(self) -> None:
        """compute_observations(), failing clearly when numObservations / numStates disagree with what it writes."""
        self.obs_buf.fill_(math.nan)
        self.states_buf.fill_(math.nan)
        try:
            self.compute_observations()
        except RuntimeError as err:
            if "size" in str(err) or "shape" in str(err):
                raise ConfigError(
                    f"{type(self).__name__}: the observation it computes does not fit env.numObservations="
                    f"{self.num_obs} / env.numStates={self.num_states} ({err})"
                ) from err
            raise
        for key, buf, size in (("numObservations", self.obs_buf, self.num_obs),
                               ("numStates", self.states_buf, self.num_states)):
            written = (~torch.isnan(buf)).any(dim=0)
            if size and not bool(written.all()):
                raise ConfigError(
                    f"{type(self).__name__}: env.{key}={size} but the task wrote only {int(written.sum())} "
                    f"columns; set env.{key} to the size the task computes"
                )
