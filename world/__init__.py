"""The procedural synthetic world: scenes, ray-cast renderer, camera walks, ground truth, the
detection noise model and scripted revisits (changes between two walks, `changes`). Ground
truth for evaluating the mapping engine.

Its own layer: the device emulator's sources and the viewer render it and the evaluation
scores against it; it imports nothing of client_sim or viewer (docs/architecture.md
"Layers")."""

from world.categories import BACKGROUND_CLASSES, CATEGORIES, Category
from world.change_visibility import SeenFrames
from world.changes import (
    CHANGE_KINDS,
    GroundTruthChange,
    RevisitScenario,
    make_revisit,
    measure_visibility,
)
from world.gt import GroundTruthCloud, gt_point_cloud
from world.noise import NOISE_PROFILES, DetectionModel, NoisyDetections
from world.render import Camera, Renderer, View, default_camera
from world.rooms import make_scene
from world.scene import SCENE_NAMES, Doorway, Room, Scene, SceneObject
from world.trajectory import walk_trajectory

__all__ = [
    "BACKGROUND_CLASSES",
    "CATEGORIES",
    "CHANGE_KINDS",
    "NOISE_PROFILES",
    "SCENE_NAMES",
    "Camera",
    "Category",
    "DetectionModel",
    "Doorway",
    "GroundTruthChange",
    "GroundTruthCloud",
    "NoisyDetections",
    "Renderer",
    "RevisitScenario",
    "Room",
    "Scene",
    "SceneObject",
    "SeenFrames",
    "View",
    "default_camera",
    "gt_point_cloud",
    "make_revisit",
    "make_scene",
    "measure_visibility",
    "walk_trajectory",
]
