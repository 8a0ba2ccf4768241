"""The ``fppm`` console script of a development install: ``fppm render`` and ``fppm converge``.

``render`` is ``addon/cli.py`` (shipped in the extension, usable alone as
``python -m fppm.addon.cli render ...``); this module adds the development
tools, which the extension does not ship, to the same parser and error
handling (``addon.cli.main``).
"""
from __future__ import annotations

import sys

from ..addon import cli
from .converge import add_parser as add_converge_parser, converge

COMMANDS = {**cli.COMMANDS, "converge": (add_converge_parser, converge)}


def main(argv=None) -> int:
    return cli.main(argv, COMMANDS)


if __name__ == "__main__":
    sys.exit(main())
