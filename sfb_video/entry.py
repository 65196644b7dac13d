"""The ``sfb-video`` console command's entry: light, so that Ctrl-C is handled from the start."""

from __future__ import annotations

import os
import sys
from typing import NoReturn


def run_command() -> NoReturn:
    """Load the command line and run it (:func:`sfb_video.cli.run`). A Ctrl-C while its modules
    load (torch and numba: about 2 s) exits with 130 and one line, as one during a run does,
    not with a traceback and death by the signal."""
    try:
        from sfb_video.cli import run
    except KeyboardInterrupt:
        print("sfb-video: interrupted; no partial output was left", file=sys.stderr, flush=True)
        os._exit(130)
    run()
