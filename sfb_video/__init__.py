"""sfb-video: Shape from Blur for videos of fast moving objects."""

__version__ = "0.1.0"
