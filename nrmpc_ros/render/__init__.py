"""Rendering of synthetic camera images for test bags: a textured room and a vectorised ray caster."""

from .raycast import Renderer, cast_rays, shade
from .scene import Scene, contains, make_scene

__all__ = ["Renderer", "Scene", "cast_rays", "contains", "make_scene", "shade"]
