"""The ``fppm`` console script of a development install: ``fppm render`` and ``fppm converge``.

``render`` is ``addon/cli.py`` (shipped in the extension, usable alone as
``python -m fppm.addon.cli render ...``); this module adds the development
tools, which the extension does not ship, to the same parser and error
handling (``addon.cli.main``).

Its first instructions catch SIGINT and SIGTERM: importing the add-on imports
bpy (about a second), and a Ctrl-C in that time must neither be lost nor raise
inside Blender's start-up.  The signals received are handed to ``addon.cli.main``
(docs/reliability.md, "Cancel").
"""
import os as _os
import signal as _signal

_EARLY_SIGNALS: list = []


def _early_handler(signum, frame):
    _EARLY_SIGNALS.append(signum)
    if len(_EARLY_SIGNALS) >= 2:          # a second signal: quit at once (addon.cli.StopFlag)
        _os._exit(130)


for _sig in (_signal.SIGINT, _signal.SIGTERM):
    _signal.signal(_sig, _early_handler)

import sys  # noqa: E402

from ..addon import cli  # noqa: E402  (imports bpy)
from .converge import add_parser as add_converge_parser, converge  # noqa: E402

COMMANDS = {**cli.COMMANDS, "converge": (add_converge_parser, converge)}


def main(argv=None, exit_process: bool = True) -> int:
    """Run ``fppm ARGV``.  exit_process (the console script): end the process
    with the exit code as soon as the command returns, with ``os._exit`` after
    flushing stdout and stderr: Blender's and numba's teardown at interpreter
    exit reset the signal handlers (a Ctrl-C then killed the process with -2)
    and could crash (-11) while a cancelled stage's daemon thread still ran.
    Every file is complete and renamed into place before the command returns.
    """
    rc = cli.main(argv, COMMANDS, early_signals=_EARLY_SIGNALS)
    if not exit_process:
        return rc
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    _os._exit(rc)


if __name__ == "__main__":
    sys.exit(main())
