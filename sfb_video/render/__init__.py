"""The differentiable mesh renderer: rasteriser, shader, and the slow reference oracle."""

from sfb_video.render.fragments import Fragments
from sfb_video.render.rasterizer import rasterize
from sfb_video.render.renderer import MeshRenderer
from sfb_video.render.shader import RenderOutput

__all__ = ["Fragments", "MeshRenderer", "RenderOutput", "rasterize"]
