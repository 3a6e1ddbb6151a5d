"""What a person sees of a running task: MuJoCo's viewer on env 0 and the test-mode / training videos.

VecTask owns one ``Display`` (``VecTask.display``) and shows it each env step after the step's work; neither the
viewer nor the recorder is part of the step the learner sees.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from isaacgymenvs_mw.sim import Simulator

if TYPE_CHECKING:
    from isaacgymenvs_mw.sim.video import VideoRecorder
    from isaacgymenvs_mw.sim.viewer import WorldViewer


class Display:
    """MuJoCo's viewer on env 0 unless ``headless`` (without a display: said once, then headless), and a video
    recorder when capture_video is on (``learning/launch.py`` attaches one with ``record``)."""

    def __init__(self, sim: Simulator, headless: bool) -> None:
        self.headless = headless
        self.viewer: WorldViewer | None = None
        self.video_recorder: VideoRecorder | None = None
        if not headless:
            from isaacgymenvs_mw.sim.viewer import open_viewer  # deferred: only interactive runs need GLFW

            self.viewer = open_viewer(sim)
            self.headless = self.viewer is None

    def record(self, recorder: VideoRecorder) -> None:
        self.video_recorder = recorder

    def show(self, control_dt: float, step: int) -> None:
        """After env step ``step``: the viewer follows env 0 in real time, the recorder takes its frame."""
        self.sync_viewer(control_dt)
        if self.video_recorder is not None:
            self.video_recorder.capture(step)

    def sync_viewer(self, control_dt: float) -> None:
        if self.viewer is not None and not self.viewer.sync(control_dt):
            self.viewer = None  # the user closed the window: keep training

    def close(self) -> None:
        if self.video_recorder is not None:
            self.video_recorder.close()  # writes out a clip in progress
            self.video_recorder = None
        if self.viewer is not None:
            self.viewer.close()
            self.viewer = None
