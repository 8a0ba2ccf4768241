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


def add_render_parser(sub) -> None:
    """``fppm render`` of the add-on plus the scale-out flags (tools/distributed.py)."""
    cli.add_render_parser(sub)
    g = sub.choices["render"].add_argument_group(
        "scale-out (Dask, docs/scale_out.md)",
        "Split each pass's photons (and light paths: integrators Light and Combined) into "
        "chunks with one random stream each; with the same "
        "--seed and --chunk, one process and any number of workers give the same image.")
    g.add_argument("--workers", type=int, metavar="N",
                   help="trace the chunks on a local Dask cluster of N processes")
    g.add_argument("--cluster", metavar="ADDRESS",
                   help="trace the chunks on the workers of the Dask scheduler at ADDRESS "
                        "(e.g. tcp://10.0.0.1:8786)")
    g.add_argument("--chunk", type=int, metavar="N",
                   help="photons or light paths per chunk (default 131072 photons, 65536 light "
                        "paths; a chunk is traced at once, about 1.2 KB per photon)")


def _spawn_without_main() -> None:
    """Keep the spawned Dask worker processes from re-running this command.

    multiprocessing's spawn method imports the parent's main module in every
    child (by path, or by name with ``python -m``): here that is this module,
    which imports bpy, and bpy does not even load in a child that inherits
    Blender's script folders on sys.path.  The workers need fppm.core alone;
    a main module with neither ``__spec__`` nor ``__file__`` (like an
    interactive session's) is not re-imported."""
    main = sys.modules.get("__main__")
    if main is not None:
        main.__spec__ = None
        main.__dict__.pop("__file__", None)


def render(a) -> int:
    """``fppm render`` with --workers / --cluster / --chunk (else the add-on's own)."""
    if a.workers is None and a.cluster is None and a.chunk is None:
        return cli.render(a)
    if a.workers is not None and a.cluster is not None:
        raise cli.CLIError(cli.EXIT_USAGE, "--workers and --cluster exclude each other: "
                                           "give one (a local cluster, or an existing scheduler).")
    if a.workers is not None and a.workers < 1:
        raise cli.CLIError(cli.EXIT_USAGE, f"--workers {a.workers}: must be at least 1.")
    if a.chunk is not None and a.chunk < 1:
        raise cli.CLIError(cli.EXIT_USAGE, f"--chunk {a.chunk}: must be at least 1 photon.")
    # The failures that need no cluster first (the render repeats them).
    cli.check_input(a.blend)
    cli.check_output(a.output, a.blend, a.overwrite, not a.no_preview)
    cli.check_numbers(a)
    from . import distributed
    client = None
    if a.workers is not None or a.cluster is not None:
        try:
            distributed.require()
        except distributed.DaskMissing as ex:
            raise cli.CLIError(cli.EXIT_USAGE, str(ex))
        if a.workers is not None:
            _spawn_without_main()
        try:
            client = distributed.connect(a.workers, a.cluster)
        except (OSError, ValueError) as ex:       # unreachable / malformed ADDRESS
            what = (f"--cluster {a.cluster}: cannot reach the Dask scheduler" if a.cluster
                    else f"--workers {a.workers}: the local Dask cluster did not start")
            raise cli.CLIError(cli.EXIT_USAGE, f"{what} ({ex}).")
    replaced = distributed.partition_fallback(a) if client is not None else None

    def on_renderer(renderer):
        if (replaced is not None and renderer.settings.integrator == "COMBINED"
                and replaced(a.file_settings.merge_weights)):
            renderer.log(distributed.PARTITION_FALLBACK)
        what = distributed.chunked_stages(distributed.local_chunk_streams(renderer, a.chunk))
        if not what:
            renderer.log(f"FPPM: integrator {renderer.settings.integrator} has no photon pass "
                         f"or light tracing: rendered in this process.")
            return
        where = "this process"
        if client is not None:
            # --frames / --animation build a renderer a frame: release the
            # last frame's stages (its scene on the workers) first.
            while stages:
                stages.pop().close()
            stages.extend(distributed.distribute(client, renderer))
            n = len(client.scheduler_info()["workers"])
            where = f"{n} Dask worker{'s' * (n != 1)}" + (f" of {a.cluster}" if a.cluster else "")
        renderer.log(f"{what}, one random stream each, on {where}.")

    stages: list = []

    a.on_renderer = on_renderer
    try:
        return cli.render(a)
    finally:
        for stage in stages:
            stage.close()
        if client is not None:
            distributed.close(client)


COMMANDS = {**cli.COMMANDS, "render": (add_render_parser, render),
            "converge": (add_converge_parser, converge)}


def main(argv=None, exit_process: bool = True) -> int:
    """Run ``fppm ARGV``.  exit_process (the console script): end the process
    with the exit code as soon as the command returns, with ``os._exit`` after
    flushing stdout and stderr (``addon.cli.exit_now``, which also removes
    Blender's session folder): Blender's and numba's teardown at interpreter
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
    cli.exit_now(rc)


if __name__ == "__main__":
    sys.exit(main())
