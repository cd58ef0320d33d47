"""The procedural synthetic world: scenes, ray-cast renderer, camera walks, ground truth and the
detection noise model. Ground truth for evaluating the mapping engine."""

from client_sim.world.categories import BACKGROUND_CLASSES, CATEGORIES, Category
from client_sim.world.gt import GroundTruthCloud, gt_point_cloud
from client_sim.world.noise import NOISE_PROFILES, DetectionModel, NoisyDetections
from client_sim.world.render import Camera, Renderer, View, default_camera
from client_sim.world.rooms import make_scene
from client_sim.world.scene import SCENE_NAMES, Doorway, Room, Scene, SceneObject
from client_sim.world.trajectory import walk_trajectory

__all__ = [
    "BACKGROUND_CLASSES",
    "CATEGORIES",
    "NOISE_PROFILES",
    "SCENE_NAMES",
    "Camera",
    "Category",
    "DetectionModel",
    "Doorway",
    "GroundTruthCloud",
    "NoisyDetections",
    "Renderer",
    "Room",
    "Scene",
    "SceneObject",
    "View",
    "default_camera",
    "gt_point_cloud",
    "make_scene",
    "walk_trajectory",
]
