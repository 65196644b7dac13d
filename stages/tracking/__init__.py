"""The tracker's parts: prediction, matching blobs to tracks, a track's life, the look back.
:mod:`sfb_video.stages.track` is the stage on top."""
