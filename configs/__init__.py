"""The named config presets, installed as the package ``sfb_video.configs`` (read with
``importlib.resources``, so they work from any folder). Each ``<name>.yaml`` fills in the typed
config of ``sfb_video/config.py``; ``--config <name>`` picks one."""
