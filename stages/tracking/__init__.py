"""The tracker's parts: prediction, the cost of each track taking each blob, one assignment of
tracks to blobs per frame, the sharing out of a blob where streaks touch, a track's life, the
look back. :mod:`sfb_video.stages.track` is the stage on top."""
