"""Scene folders: ``load_scene(path) -> Scene`` for every common format, writers, normalisation."""
from .base import Layout, Scene, SceneError
from .images import find_images, read_rgb, resize
from .writers import write_blender_transforms, write_nerfstudio_transforms

__all__ = ["Layout", "Scene", "SceneError", "find_images", "read_rgb", "resize",
           "write_blender_transforms", "write_nerfstudio_transforms"]
