"""Pipeline stages, one module each, from typed input artifacts to typed output artifacts.

video -> frames (read) -> background -> detections and tracks (detect, track) -> fits (fit,
masks) -> exports (export, novel_views); ``process`` chains them and owns the run folder. The
stages use the library in ``sfb_video``; each can run and be tested alone.
"""
