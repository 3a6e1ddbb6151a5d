"""The observation terms' earlier home, kept so task projects written against the earlier docs import unchanged
(``from isaacgymenvs_mw.tasks.base.observations import ObsTerm``). The terms live in ``observation_terms.py``;
``Observations``, which composes them into groups, in ``observation_composer.py``. New code imports from there."""

from isaacgymenvs_mw.tasks.base.observation_terms import (IMAGE_OUTPUTS, ImageGroup, ImageTerm, ObsLayout, ObsTerm,
                                                          camera_terms, sensor_terms)

__all__ = ["IMAGE_OUTPUTS", "ImageGroup", "ImageTerm", "ObsLayout", "ObsTerm", "camera_terms", "sensor_terms"]
