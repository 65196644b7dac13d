"""Pipeline stages, one module each, from typed input artifacts to typed output artifacts.

video -> frames -> background -> detections -> crops -> fit -> results -> exporters
(see DESIGN.md). The stages use the library in ``sfb_video``; each can run and be tested alone.
"""
