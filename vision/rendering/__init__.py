"""Synthetic overhead frames of the phantom with the electrode array, and their exact truth.

The renderer runs the measurement backwards: geometry (:mod:`tympani.vision.geometry`) → image.
Ground truth is computed from the very centreline that is drawn, with the angles' definitions
(docs/file-formats.md, :func:`tympani.vision.angles.contact_angles`).

Pieces, from geometry to file, one module a step:

* :mod:`.centreline` — :func:`array_centreline`, the array's centreline for a tip angle and
  contact start angle; :func:`pose_at_depth`, the same for an insertion depth, following a
  :class:`ContactPolicy`;
* :mod:`.appearance` — :class:`Appearance`, the grey levels, and the random draws of a look,
  a camera pose and a contact policy (:func:`random_appearance`, :func:`random_pose`,
  :func:`random_policy`);
* :mod:`.nuisances` — :class:`Nuisance`, :func:`random_nuisance`, :func:`random_harsh_nuisance`:
  what degrades a frame (noise, blur, uneven light and shadows, clutter and the gripper, bubbles
  in the fluid, doubled walls, glints, motion blur, JPEG);
* :mod:`.bubbles` — the channel's middle line (:func:`channel_path`) and the air bubbles on it;
* :mod:`.scene` — :class:`Scene`, a static view (pose, appearance, nuisances) that draws frames;
* :mod:`.video` — :func:`render_video`, a whole insertion (:class:`VideoSpec`) to mp4 or a PNG
  folder, with a truth table;
* :mod:`.lens` — :func:`distort`, what a lens with a given :class:`tympani.vision.frames.LensCalibration`
  makes of a rendered (ideal pinhole) frame.
"""

from __future__ import annotations

from tympani.vision.rendering.appearance import Appearance, random_appearance, random_policy, random_pose
from tympani.vision.rendering.bubbles import BubbleLook, ChannelPath, bubble_ahead_of_tip, channel_path
from tympani.vision.rendering.centreline import (
    ArrayShape,
    ArrayState,
    ContactPolicy,
    array_at_angles,
    array_centreline,
    pose_at_depth,
)
from tympani.vision.rendering.lens import distort
from tympani.vision.rendering.nuisances import Nuisance, random_harsh_nuisance, random_nuisance
from tympani.vision.rendering.scene import Scene
from tympani.vision.rendering.video import VideoSpec, render_video, spec_to_dict

__all__ = [
    "ArrayShape",
    "ContactPolicy",
    "ArrayState",
    "Appearance",
    "Nuisance",
    "VideoSpec",
    "Scene",
    "array_centreline",
    "array_at_angles",
    "pose_at_depth",
    "random_pose",
    "random_policy",
    "random_appearance",
    "random_nuisance",
    "random_harsh_nuisance",
    "BubbleLook",
    "ChannelPath",
    "channel_path",
    "bubble_ahead_of_tip",
    "render_video",
    "spec_to_dict",
    "distort",
]
