"""``fppm render``: render a .blend file with FPPM from the command line (Blender as a module).

    fppm render SCENE.blend -o OUT.exr [--frame N] [--time-limit S] [--passes N]
                [--photons N] [--mode combined|fppm|ppm|path|light] [--seed N] [--resolution PCT]
                [--merge-weights partition|mis]
                [--checkpoint DIR [--checkpoint-every S] [--resume]] [--overwrite]

This module is shipped in the extension and runs alone
(``python -m fppm.addon.cli render ...``).  The ``fppm`` console script of a
development install is ``tools/cli.py``: the same ``render`` sub-command plus
the development tools (``fppm converge``).  Nothing here imports ``tools``.

The file is opened with its embedded scripts disabled.  Settings come from
the file's ``scene.fppm`` (defaults when the file never had the add-on), then
from the flags.  The render goes through the FPPM RenderEngine with
``bpy.ops.render.render`` (Blender's render-mode depsgraph: the same export,
and so the same image, as pressing F12): :func:`open_blend` then
:func:`render_scene`, which ``fppm converge`` uses too.  Output: a multilayer
EXR (Combined plus the enabled AOV passes) and a PNG preview beside it through
the scene's view transform, both written atomically (``core.io.atomic``).

Exit codes (also in README.md):
    0    the image was written
    1    internal error (a bug: the traceback is printed)
    2    usage error: bad flags or an invalid setting
    3    the input file is missing, unreadable or not a .blend file
    4    the scene cannot be rendered (no camera, no lights, nothing visible, ...)
    5    the output file cannot be written, or would replace the input, a link or a device
    6    --resume: the checkpoint is from another scene or other settings, or damaged;
         or the checkpoint folder is in use by another render
    7    the render would not fit in memory (the message names the setting to lower)
    130  cancelled with Ctrl-C or SIGTERM at any instant: the last complete pass
         was written first, if there was one
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import struct
import subprocess
import sys
import tempfile
import time
import traceback

EXIT_OK, EXIT_INTERNAL, EXIT_USAGE, EXIT_INPUT, EXIT_SCENE, EXIT_OUTPUT = 0, 1, 2, 3, 4, 5
EXIT_CANCELLED = 130
EXIT_CHECKPOINT, EXIT_MEMORY = 6, 7

# First bytes of a .blend: plain, gzip-compressed (old files), zstd-compressed (3.0+).
_BLEND_MAGIC = (b"BLENDER", b"\x1f\x8b", b"\x28\xb5\x2f\xfd")


class CLIError(Exception):
    def __init__(self, code: int, msg: str):
        super().__init__(msg)
        self.code = code


def add_render_parser(sub) -> None:
    """Add the ``render`` sub-command to an argparse sub-parsers object."""
    r = sub.add_parser("render", help="render a .blend file to a multilayer EXR and a PNG preview",
                       description="Render SCENE.blend with FPPM.")
    r.add_argument("blend", metavar="SCENE.blend", help="the .blend file (scripts are not run)")
    r.add_argument("-o", "--output", required=True, metavar="OUT.exr",
                   help="multilayer EXR to write; the PNG preview goes beside it (OUT.png)")
    fr = r.add_mutually_exclusive_group()
    fr.add_argument("--frame", type=int, metavar="N", help="frame to render (default: the file's)")
    fr.add_argument("--frames", metavar="LIST",
                    help="render these frames, one image each, in one process: Blender's -f "
                         "list, e.g. 1,3,5..10; -o's last run of # becomes the frame number "
                         "(out_####.exr: out_0005.exr), else four digits go before .exr")
    fr.add_argument("-a", "--animation", action="store_true",
                    help="render the file's frame range (Frame Start to End by Step), one "
                         "image per frame, as blender -a")
    r.add_argument("--time-limit", type=float, metavar="S",
                   help="stop after S seconds of passes (0 = no limit)")
    r.add_argument("--passes", type=int, metavar="N", help="maximum passes (0 = no limit)")
    r.add_argument("--photons", type=int, metavar="N", help="photons per pass")
    r.add_argument("--mode", choices=("combined", "fppm", "ppm", "path", "light"),
                   help="the integrator (default: the file's; Combined when it never set one): "
                        "combined: path and light tracing weighted by MIS, with photon merging "
                        "(integrator COMBINED); fppm: photon mapping with the frequency-adapted "
                        "kernel; ppm: plain progressive photon mapping; "
                        "path: path tracing (integrator PATH); "
                        "light: light tracing alone (photon paths connected to the camera)")
    r.add_argument("--seed", type=int, metavar="N", help="random seed")
    r.add_argument("--merge-weights", choices=("partition", "mis"),
                   help="combined: photon merging by path classes (partition) or as an MIS "
                        "strategy (mis); default: the file's")
    r.add_argument("--resolution", type=int, metavar="PCT",
                   help="resolution percentage (1-1000), overriding the file's")
    r.add_argument("--no-preview", action="store_true", help="do not write the PNG preview")
    r.add_argument("--overwrite", action="store_true",
                   help="allow -o (or its PNG preview) to replace a symbolic link or the input "
                        "file itself (devices, FIFOs and folders are never replaced)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    r.add_argument("--checkpoint", metavar="DIR",
                   help="save the progressive state in DIR (atomically) every --checkpoint-every "
                        "seconds and when the render ends or is cancelled")
    r.add_argument("--checkpoint-every", type=float, default=30.0, metavar="S",
                   help="seconds between checkpoints (default 30; 0 = after every pass)")
    r.add_argument("--resume", action="store_true",
                   help="continue from the checkpoint in --checkpoint DIR (same scene and settings)")
    r.add_argument("--skip-existing", action="store_true",
                   help="--frames / --animation: leave out the frames whose EXR exists already "
                        "(run the same command again to finish an interrupted animation)")


def build_parser(commands: dict) -> argparse.ArgumentParser:
    """The ``fppm`` parser with one sub-command per entry of ``commands``
    (``{name: (add_parser(sub), run(args) -> exit code)}``)."""
    p = argparse.ArgumentParser(
        prog="fppm",
        description="FPPM: frequency-based progressive photon mapping for Blender scenes.",
        epilog="Exit codes: 0 ok, 1 internal error, 2 usage, 3 input file problem, "
               "4 scene error, 5 output not writable, 6 checkpoint refused, 7 not enough memory, "
               "130 cancelled (partial image written).")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add_parser, _run in commands.values():
        add_parser(sub)
    return p


# ---------------------------------------------------------------------------
# checks that need no bpy (fast failures)

def check_input(path: str) -> None:
    if not os.path.exists(path):
        raise CLIError(EXIT_INPUT, f"input file '{path}' does not exist.")
    if not os.path.isfile(path):
        raise CLIError(EXIT_INPUT, f"input '{path}' is not a file.")
    try:
        with open(path, "rb") as fh:
            head = fh.read(8)
    except OSError as ex:
        raise CLIError(EXIT_INPUT, f"cannot read '{path}': {ex.strerror}.")
    if not head.startswith(_BLEND_MAGIC):
        raise CLIError(EXIT_INPUT, f"'{path}' is not a .blend file.")


# ---------------------------------------------------------------------------
# a damaged .blend must not crash the process (docs/reliability.md, "Bad input")

# The block codes of a .blend: these, or an ID's two upper-case letters and two
# NULs (b"OB\0\0").  A bit flip that turned DATA into another word crashed
# Blender's reader (docs/reliability.md).
_BLOCK_CODES = frozenset((b"DATA", b"GLOB", b"DNA1", b"TEST", b"REND", b"USER", b"ENDB"))
_UPPER = frozenset(b"ABCDEFGHIJKLMNOPQRSTUVWXYZ")


def _known_code(code: bytes) -> bool:
    return code in _BLOCK_CODES or (code[2:] == b"\0\0" and set(code[:2]) <= _UPPER)


def _sdna_struct_count(dna: bytes, endian: str) -> int | None:
    """Number of structs in a DNA1 block's data (SDNA NAME TYPE TLEN STRC), or None."""
    def strings(i: int, tag: bytes) -> tuple[int, int]:
        """After the 4-byte tag at i: a count and that many NUL-ended strings;
        returns (count, the 4-aligned offset after them)."""
        if dna[i:i + 4] != tag:
            raise ValueError(tag)
        n = struct.unpack_from(endian + "i", dna, i + 4)[0]
        i += 8
        for _ in range(n):
            i = dna.index(b"\0", i) + 1
        return n, (i + 3) & ~3
    try:
        _, i = strings(4, b"NAME")                     # after b"SDNA"
        n, i = strings(i, b"TYPE")
        if dna[i:i + 4] != b"TLEN":
            return None
        i = (i + 4 + 2 * n + 3) & ~3
        if dna[i:i + 4] != b"STRC":
            return None
        return struct.unpack_from(endian + "i", dna, i + 4)[0]
    except (ValueError, struct.error):
        return None


def _walk_blocks(read, skip, size: int | None) -> str | None:
    """Walk the file-block chain of an uncompressed .blend stream to ENDB.

    read(n) -> bytes (fewer at the end), skip(n) -> bytes skipped; size:
    the stream's length when known.  Returns None when the chain is sound,
    else what is wrong.  Only headers are read (a block's data is skipped):
    the header magic and version, every block's code and lengths, that
    the blocks end exactly at ENDB and that the DNA block is there.
    """
    head = read(12)
    if len(head) < 12 or not head.startswith(b"BLENDER"):
        return "no .blend header"
    if head[7:9].isdigit():
        # Blender 5 header: BLENDER + header size + '-' + file format + 'v' + version.
        hsize = int(head[7:9])
        head += read(max(0, hsize - 12))
        if (len(head) != hsize or head[9:10] != b"-" or head[10:12] != b"01"
                or head[12:13] not in (b"v", b"V") or not head[13:hsize].isdigit()):
            return f"unknown header {head[:17]!r}"
        endian = "<" if head[12:13] == b"v" else ">"
        bhead = struct.Struct(endian + "4siQqq")      # code, SDNA index, old address, len, nr
        fields = lambda b: (b[0], b[3], b[4], b[1])    # noqa: E731
        pos = hsize
    else:
        ptr, end, version = head[7:8], head[8:9], head[9:12]
        if ptr not in (b"_", b"-") or end not in (b"v", b"V") or not version.isdigit():
            return f"unknown header {head!r}"
        endian = "<" if end == b"v" else ">"
        bhead = struct.Struct(endian + ("4siQii" if ptr == b"-" else "4siIii"))
        fields = lambda b: (b[0], b[1], b[4], b[3])    # noqa: E731
        pos = 12
    n_structs = None
    max_sdna = 0
    while True:
        raw = read(bhead.size)
        if len(raw) < bhead.size:
            return f"truncated at byte {pos} (no end block)"
        code, length, nr, sdna = fields(bhead.unpack(raw))
        pos += bhead.size
        if code == b"ENDB":
            if n_structs is None:
                return "no DNA block"
            if max_sdna >= n_structs:
                return f"a block names struct {max_sdna} of {n_structs}"
            return None
        if not _known_code(code):
            return f"garbled block code {code!r} at byte {pos - bhead.size}"
        if length < 0 or nr < 0 or sdna < 0 or (size is not None and pos + length > size):
            return f"block {code.decode('latin-1')!r} at byte {pos - bhead.size} has a bad length"
        max_sdna = max(max_sdna, sdna)
        if code == b"DNA1":
            data = read(length)
            n_structs = _sdna_struct_count(data, endian) if len(data) == length else None
            if not data.startswith(b"SDNANAME") or not n_structs or n_structs < 0:
                return "damaged DNA block"
        elif skip(length) < length:
            return f"truncated at byte {pos} (no end block)"
        pos += length


def blend_damage(path: str) -> str | None:
    """None when ``path`` is a sound .blend (plain, gzip or zstd), else what is wrong.

    A cheap structural check done before Blender reads the file: Blender's
    reader trusts the file, and a damaged one can crash it (a bit-flipped
    file segfaulted it, exit 139).  Plain files: only the block headers are
    read.  Compressed files are decompressed as a stream (zstd needs the
    ``zstandard`` module, which bpy installs; without it only the header is
    checked).
    """
    import gzip
    try:
        fh = open(path, "rb")
    except OSError as ex:
        return ex.strerror
    with fh:
        magic = fh.read(7)
        fh.seek(0)
        try:
            if magic.startswith(b"BLENDER"):
                size = os.fstat(fh.fileno()).st_size

                def skip(n):
                    start = fh.tell()
                    fh.seek(min(start + n, size))
                    return fh.tell() - start
                return _walk_blocks(fh.read, skip, size)
            if magic.startswith(b"\x1f\x8b"):
                stream = gzip.GzipFile(fileobj=fh)
            elif magic.startswith(b"\x28\xb5\x2f\xfd"):
                try:
                    import zstandard
                except ImportError:
                    return None
                stream = zstandard.ZstdDecompressor().stream_reader(fh, read_across_frames=True)
            else:
                return "not a .blend file"

            def skip_stream(n):
                done = 0
                while done < n:
                    got = len(stream.read(min(n - done, 1 << 20)))
                    if got == 0:
                        break
                    done += got
                return done
            return _walk_blocks(stream.read, skip_stream, None)
        except (OSError, EOFError, ValueError, struct.error) as ex:
            return f"cannot decompress it ({ex})"
        except Exception as ex:   # zstandard.ZstdError and the like
            return f"cannot decompress it ({type(ex).__name__}: {ex})"


# The child that opens a suspect file: Blender's reader, scripts disabled.
_PROBE = ("import sys\n"
          "import bpy\n"
          "try:\n"
          "    bpy.ops.wm.open_mainfile(filepath=sys.argv[1], load_ui=False, use_scripts=False)\n"
          "except RuntimeError as ex:\n"
          "    print(str(ex).strip(), file=sys.stderr)\n"
          "    sys.exit(3)\n")


def probe_command(path: str) -> list:
    """The command that opens ``path`` in a child process (tests replace it)."""
    return [sys.executable, "-c", _PROBE, os.path.abspath(path)]


def probe_blend(path: str, reason: str, should_stop=None) -> bool:
    """Open a suspect ``path`` in a child process first; CLIError(EXIT_INPUT) if
    Blender fails or crashes there.  Returns False when should_stop() turned
    true while waiting (the child is killed), True when the child read it."""
    # The child's Blender session folder (<temp>/blender_<random>) goes in a
    # folder of this process's, removed once the child has ended: a child
    # that crashes on the file, or is killed, cannot remove it itself.
    with tempfile.TemporaryDirectory(prefix="fppm-probe-", ignore_cleanup_errors=True) as tmp:
        env = dict(os.environ, TMPDIR=tmp, TEMP=tmp, TMP=tmp)
        proc = subprocess.Popen(probe_command(path), stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env,
                                start_new_session=True)   # Ctrl-C goes to the parent only
        err = b""
        while True:
            try:
                _, err = proc.communicate(timeout=0.05)
                break
            except subprocess.TimeoutExpired:
                if should_stop is not None and should_stop():
                    proc.kill()
                    proc.communicate()
                    return False
    rc = proc.returncode
    if rc == 0:
        return True
    if rc < 0:
        try:
            sig = signal.Signals(-rc).name
        except ValueError:
            sig = f"signal {-rc}"
        raise CLIError(EXIT_INPUT, f"cannot open '{path}': the file is damaged ({reason}) and "
                                   f"Blender's reader crashed on it ({sig}): restore it from a "
                                   f"backup (Blender keeps the previous save as '.blend1').")
    lines = [ln for ln in err.decode("utf-8", "replace").splitlines() if ln.strip()]
    said = lines[-1].strip() if rc == EXIT_INPUT and lines else f"Blender exited with code {rc}"
    raise CLIError(EXIT_INPUT, f"cannot open '{path}': the file is damaged ({reason}): {said}")


def check_output(path: str, blend: str | None = None, overwrite: bool = False,
                 preview: bool = True) -> None:
    """Refuse an output that cannot be written or whose replacement would destroy data.

    The output must end in .exr (the format is chosen by the extension, and
    the preview is the same name with .png).  Neither it nor its preview may
    be a folder, a device, a FIFO or a socket; a symbolic link or the input
    file itself only with ``overwrite`` (core.io.atomic.check_target).
    """
    from ..core.io.atomic import check_target

    d = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise CLIError(EXIT_OUTPUT, f"output '{path}' is a folder.")
    if os.path.splitext(path)[1].lower() != ".exr":
        raise CLIError(EXIT_USAGE, f"-o '{path}': the output must be an OpenEXR file ending in "
                                   f".exr (the PNG preview is written beside it, with .png).")
    if not os.path.isdir(d):
        raise CLIError(EXIT_OUTPUT, f"cannot write '{path}': the folder '{d}' does not exist.")
    if not os.access(d, os.W_OK | os.X_OK):
        raise CLIError(EXIT_OUTPUT, f"cannot write '{path}': the folder '{d}' is not writable.")
    for target in (path, preview_path(path)) if preview else (path,):
        try:
            check_target(target, protected=(blend,) if blend else (), overwrite=overwrite)
        except OSError as ex:
            raise CLIError(EXIT_OUTPUT, f"will not write '{target}': {ex.strerror or ex}.")
    if os.path.exists(path) and not os.access(path, os.W_OK):
        raise CLIError(EXIT_OUTPUT, f"cannot write '{path}': the file is read-only.")


def preview_path(exr_path: str) -> str:
    root, ext = os.path.splitext(exr_path)
    return (root if ext.lower() == ".exr" else exr_path) + ".png"


def overrides_from_args(a) -> dict:
    kw = {}
    if a.time_limit is not None:
        kw["time_limit"] = float(a.time_limit)
        if a.passes is None and a.time_limit > 0:
            kw["max_passes"] = 0  # a time limit alone means: passes until the time is up
    if a.passes is not None:
        kw["max_passes"] = a.passes
    if a.photons is not None:
        kw["photons_per_pass"] = a.photons
    if a.seed is not None:
        kw["seed"] = a.seed
    if getattr(a, "merge_weights", None) is not None:
        kw["merge_weights"] = a.merge_weights.upper()
    if a.mode == "light":
        kw["integrator"] = "LIGHT"
    elif a.mode == "path":
        kw["integrator"] = "PATH"
    elif a.mode == "combined":
        kw["integrator"] = "COMBINED"
    elif a.mode is not None:
        kw["integrator"] = "PHOTON"
        kw["use_frequency"] = a.mode == "fppm"
    return kw


# ---------------------------------------------------------------------------
# progress

class Progress:
    """A one-line progress bar on stderr (a line per second when not a terminal)."""

    def __init__(self, quiet: bool, stream=None):
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.last = 0.0
        self.shown = False

    def __call__(self, pr, settings) -> None:
        if self.quiet:
            return
        from .engine import progress_fraction
        f = progress_fraction(pr, settings)
        now = time.monotonic()
        done = f >= 1.0
        if not self.tty and not done and now - self.last < 1.0:
            return
        self.last = now
        n = 24
        k = int(round(f * n))
        line = f"[{'#' * k}{'.' * (n - k)}] {f * 100:3.0f}%  {pr.stats_line()}"
        if self.tty:
            self.stream.write("\r" + line + "\x1b[K")
        else:
            self.stream.write(line + "\n")
        self.stream.flush()
        self.shown = True

    def close(self) -> None:
        if self.shown and self.tty:
            self.stream.write("\n")
            self.stream.flush()


# ---------------------------------------------------------------------------

def _say(msg: str) -> None:
    print(msg, flush=True)


def _write_outputs(a, bpy, scene, sess, out_path, elapsed_wall) -> list[str]:
    """Write the EXR (and the PNG preview); return the written paths."""
    import numpy as np

    from ..core.io.atomic import default_file_mode, ensure_free_space, replace_atomically
    from ..core.io.exr import layers_size_bound, write_exr
    from ..core.settings import field_names

    pr = sess.result
    img = np.array(pr.image, np.float32, copy=True)
    if sess.gain != 1.0:
        img[..., :3] *= np.float32(sess.gain)
    layers = {"Combined": img}
    for name, arr in pr.aovs.items():
        # A shader AOV's name may hold a dot, which would split the layer
        # when the EXR is read back (core.io.exr): an underscore instead.
        layers[name.replace(".", "_")] = arr
    st = sess.settings
    meta = {
        "fppm:version": "0.1.0",
        "fppm:source": os.path.basename(a.blend),
        "fppm:frame": str(scene.frame_current),
        "fppm:passes": str(pr.pass_index),
        "fppm:photons": str(pr.photons_emitted),
        "fppm:elapsed": f"{pr.elapsed:.3f}",
        "fppm:cancelled": str(bool(sess.cancelled)).lower(),
        "fppm:settings": json.dumps({k: getattr(st, k) for k in field_names()}, sort_keys=True),
        "fppm:settings_digest": st.digest(),
    }
    if getattr(sess, "renderer", None) is not None:
        # The render plan: which stages ran, and what was left out and why.
        meta.update(sess.renderer.plan.metadata())
        # The Cryptomatte manifests (their layers here: "CryptoObject00", ...).
        from ..core.sppm.cryptomatte import scene_metadata
        meta.update(scene_metadata(sess.renderer.scene, list(pr.aovs), ""))
    h, w = img.shape[:2]
    try:
        # Room for both files before writing either (upper bounds).
        need = layers_size_bound(layers, meta) + (0 if a.no_preview else png_size_bound(w, h))
        ensure_free_space(out_path, need)
        write_exr(out_path, layers, meta)
    except OSError as ex:
        raise CLIError(EXIT_OUTPUT, _os_error_text(ex, out_path))
    written = [out_path]
    if not a.no_preview:
        png = preview_path(out_path)
        rr = bpy.data.images.get("Render Result")
        if rr is not None:
            isettings = scene.render.image_settings
            try:
                with replace_atomically(png, suffix=".png", mode=default_file_mode(),
                                        verify=verify_png) as tmp:
                    isettings.file_format = 'PNG'
                    isettings.color_mode = 'RGBA'
                    isettings.color_depth = '8'
                    # save_render applies the scene's view transform and look.
                    # It fails silently on a full disk (an empty or truncated
                    # file): verify_png catches that before the rename.
                    rr.save_render(filepath=tmp, scene=scene)
                written.append(png)
            except (OSError, RuntimeError) as ex:
                detail = (ex.strerror or ex) if isinstance(ex, OSError) else ex
                raise CLIError(EXIT_OUTPUT, f"cannot write the preview '{png}': {detail}.")
    return written


def _os_error_text(ex: OSError, path: str) -> str:
    """One sentence for an OSError (its own sentence when it has one)."""
    text = str(ex.strerror or ex).strip()
    if path not in text:
        text = f"Cannot write '{path}': {text}"
    return text if text.endswith(".") else text + "."


def png_size_bound(w: int, h: int) -> int:
    """Upper bound on an 8-bit RGBA PNG of w x h: the raw scanlines (a filter byte
    each) after deflate's worst case (5 bytes per 16 KiB stored block), the
    chunk headers of IDAT chunks of 8 KiB and 4 KiB of other chunks."""
    raw = (4 * w + 1) * h
    return int(raw * (1 + 5 / 16384)) + 12 * (raw // 8192 + 2) + 4096


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"


def verify_png(path: str, size: tuple | None = None) -> None:
    """Raise OSError unless ``path`` is a complete PNG (of ``size`` = (w, h) when
    given): signature, IHDR and the IEND chunk at the very end (Blender's ``save_render`` does not
    report a full disk: it leaves an empty or truncated file)."""
    import errno
    import struct
    try:
        with open(path, "rb") as fh:
            head = fh.read(24)
            fh.seek(max(os.path.getsize(path) - 12, 0))
            tail = fh.read(12)
    except OSError as ex:
        raise OSError(ex.errno, f"the preview written cannot be read back ({ex.strerror})")
    if len(head) < 24 or not head.startswith(_PNG_SIGNATURE) or head[12:16] != b"IHDR":
        raise OSError(errno.EIO, "the preview written is not a PNG (is the disk full?)")
    dims = struct.unpack(">II", head[16:24])
    if (size is not None and dims != tuple(size)) or min(dims) < 1 or tail != _PNG_IEND:
        raise OSError(errno.EIO, "the preview written is incomplete (is the disk full?)")


def check_checkpoint_args(a) -> None:
    if a.resume and not a.checkpoint:
        raise CLIError(EXIT_USAGE, "--resume needs --checkpoint DIR (the folder of the checkpoint).")
    if not (a.checkpoint_every >= 0 and a.checkpoint_every != float("inf")):
        raise CLIError(EXIT_USAGE, f"--checkpoint-every {a.checkpoint_every}: must be a number "
                                   f"of seconds >= 0 (0 = after every pass).")
    if not a.checkpoint:
        return
    d = a.checkpoint
    if os.path.exists(d) and not os.path.isdir(d):
        raise CLIError(EXIT_OUTPUT, f"--checkpoint '{d}' is not a folder.")
    try:
        os.makedirs(d, exist_ok=True)
    except OSError as ex:
        raise CLIError(EXIT_OUTPUT, f"cannot create the checkpoint folder '{d}': {ex.strerror or ex}.")
    if not os.access(d, os.W_OK | os.X_OK):
        raise CLIError(EXIT_OUTPUT, f"the checkpoint folder '{d}' is not writable.")


class Checkpointer:
    """Keeps ``--checkpoint DIR`` up to date with ``Renderer.state_dict()``.

    Saved only between passes (``on_pass``: a complete pass) at most every
    ``every`` seconds, and once more when the render ends or is cancelled.
    A failed save (full disk) is a warning: the render goes on.
    """

    def __init__(self, directory: str, every: float, log):
        self.dir, self.every, self.log = directory, every, log
        self.last_save = time.monotonic()
        self.saved_pass = 0

    def resume(self, renderer) -> None:
        from ..core.io import checkpoint
        if not checkpoint.exists(self.dir):
            self.log(f"No checkpoint in '{self.dir}' yet: starting from pass 1.")
            return
        renderer.load_state(checkpoint.load(self.dir, renderer.STATE_KEYS))  # CheckpointMismatch
        self.saved_pass = renderer.pass_index
        self.log(f"Resumed from '{checkpoint.checkpoint_path(self.dir)}': "
                 f"{renderer.pass_index} passes, {renderer.photons_emitted:,} photons done.")

    def after_pass(self, renderer) -> None:
        if time.monotonic() - self.last_save >= self.every:
            self.save(renderer)

    def save(self, renderer) -> bool:
        """True when the checkpoint holds the renderer's current pass."""
        from ..core.io import checkpoint
        if renderer is None or renderer.pass_index == 0:
            return False
        if renderer.pass_index == self.saved_pass:
            return True
        try:
            checkpoint.save(self.dir, renderer.state_dict())
        except OSError as ex:
            self.log(f"Warning: {ex.strerror or ex}; the render goes on.")
            return False
        self.saved_pass = renderer.pass_index
        self.last_save = time.monotonic()
        return True


def _state_kept(ckpt, renderer) -> str:
    """After an output error: where the render state is, and how to get the image."""
    from ..core.io import checkpoint
    if renderer is None or renderer.pass_index == 0:
        return ""
    n = renderer.pass_index
    if ckpt is not None and ckpt.saved_pass == n:
        return (f" The render state ({n} passes) is kept in the checkpoint folder '{ckpt.dir}': "
                f"fix the problem, then run the same command with --resume to write the image "
                f"without rendering again.")
    try:
        d = tempfile.mkdtemp(prefix="fppm-state-")
        checkpoint.save(d, renderer.state_dict())
    except OSError as ex:
        return f" The render state could not be saved either: {ex.strerror or ex}."
    return (f" The render state ({n} passes) is kept in '{d}': fix the problem, then run the "
            f"same command with --checkpoint {d} --resume to write the image without "
            f"rendering again.")


def open_blend(path: str, frame=None, resolution=None, should_stop=None):
    """Open ``path`` (scripts disabled) with the add-on registered; returns its scene.

    frame: the frame to set (None: the file's); resolution: the resolution
    percentage (None: the file's).  Raises CLIError(EXIT_INPUT) when Blender
    cannot read the file, also when it would crash reading it: a file that
    fails :func:`blend_damage` is opened in a child process first
    (:func:`probe_blend`).  Returns None if should_stop() turned true then.
    """
    import bpy

    from .. import addon

    damage = blend_damage(path)
    if damage is not None and not probe_blend(path, damage, should_stop):
        return None
    addon.register()
    try:
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path), load_ui=False,
                                 use_scripts=False)
    except RuntimeError as ex:
        raise CLIError(EXIT_INPUT, f"cannot open '{path}': {str(ex).strip()}")
    scene = bpy.context.scene
    if frame is not None:
        scene.frame_set(frame)
    if resolution is not None:
        scene.render.resolution_percentage = resolution
    return scene


def render_size(scene) -> tuple[int, int]:
    """(width, height) in pixels the scene renders at: the exporter's rule."""
    rd = scene.render
    return (rd.resolution_x * rd.resolution_percentage // 100,
            rd.resolution_y * rd.resolution_percentage // 100)


def render_scene(scene, overrides: dict, sess) -> None:
    """Render the open ``scene`` with FPPM: its settings, then ``overrides``.

    The one path from an opened .blend file (:func:`open_blend`) to a
    sequence of rendered passes: ``fppm render`` and ``fppm converge`` both
    render through it, with Blender's render-mode depsgraph (the F12 scene).

    overrides: ``{RenderSettings field: value}`` applied over the file's
      ``scene.fppm`` (written back to it, so the EXR metadata and the engine
      see the same settings).
    sess: an ``engine.RenderSession``; its ``on_pass(result, settings)`` is
      called after every pass, ``should_stop()`` is polled, and after the
      render it holds the result, the renderer and the settings.
    Raises CLIError: invalid settings, no camera, an empty resolution, or the
    error that stopped the render (mapped to its exit code).
    """
    import bpy

    from ..core.errors import CheckpointMismatch, FPPMError, MemoryBudgetError
    from ..core.settings import SettingsError
    from . import engine
    from .export import NO_CAMERA
    from .properties import apply_settings, settings_from_scene

    try:
        settings = settings_from_scene(scene).replace(**overrides).validate()
    except SettingsError as ex:
        raise CLIError(EXIT_USAGE, str(ex))
    try:
        apply_settings(scene.fppm, settings)
    except (OverflowError, ValueError, TypeError):
        pass                       # check_stored names the value Blender could not hold
    check_stored(scene.fppm, overrides)
    scene.render.engine = "FPPM"
    if scene.camera is None:
        raise CLIError(EXIT_SCENE, NO_CAMERA)
    w, h = render_size(scene)
    if w < 1 or h < 1:
        # Blender would only say "Image too small".
        rd = scene.render
        raise CLIError(EXIT_SCENE, f"The render resolution {w}x{h} is empty "
                                   f"({rd.resolution_x}x{rd.resolution_y} at "
                                   f"{rd.resolution_percentage}%): raise the resolution or "
                                   f"its percentage.")
    with engine.session(sess):
        try:
            bpy.ops.render.render()
        except RuntimeError:
            pass  # the engine's report(); the cause is in sess.error
    if sess.error is not None:
        if isinstance(sess.error, SettingsError):
            raise CLIError(EXIT_USAGE, str(sess.error))
        if isinstance(sess.error, CheckpointMismatch):
            raise CLIError(EXIT_CHECKPOINT, f"{sess.error} Render without --resume to start "
                                            f"over (the checkpoint is then replaced).")
        if isinstance(sess.error, MemoryBudgetError):
            raise CLIError(EXIT_MEMORY, str(sess.error))
        if isinstance(sess.error, FPPMError):
            raise CLIError(EXIT_SCENE, str(sess.error))
        raise CLIError(EXIT_INTERNAL, f"internal error: {type(sess.error).__name__}: {sess.error}")


# Blender's frame range (MINAFRAME .. MAXFRAME in DNA_scene_types.h).
FRAME_RANGE = (-1048574, 1048574)
# --time-limit: 0 (no limit) or this many seconds at least (Blender stores it
# as a float32 property: 1e-40 s would become a subnormal or 0).
MIN_TIME_LIMIT = 1e-3
# The flag each overridden setting comes from (for the messages).
_FLAG_OF = {"time_limit": "--time-limit", "max_passes": "--passes",
            "photons_per_pass": "--photons", "seed": "--seed", "use_frequency": "--mode",
            "merge_weights": "--merge-weights"}


def check_numbers(a) -> None:
    """Usage errors of numeric flags the settings cannot see (exit code 2)."""
    import math
    if a.resolution is not None and not 1 <= a.resolution <= 1000:
        raise CLIError(EXIT_USAGE, f"--resolution {a.resolution}: must be in [1, 1000].")
    if a.frame is not None and not FRAME_RANGE[0] <= a.frame <= FRAME_RANGE[1]:
        raise CLIError(EXIT_USAGE, f"--frame {a.frame}: must be in [{FRAME_RANGE[0]}, "
                                   f"{FRAME_RANGE[1]}] (Blender's frame range).")
    if a.time_limit is not None:
        t = a.time_limit
        if not math.isfinite(t):       # (negative: the settings' own message)
            raise CLIError(EXIT_USAGE, f"--time-limit {t}: must be a number of seconds >= 0 "
                                       f"(0 = no limit).")
        if 0 < t < MIN_TIME_LIMIT:
            raise CLIError(EXIT_USAGE, f"--time-limit {t}: must be 0 (no limit) or at least "
                                       f"{MIN_TIME_LIMIT} s.")


def parse_frames(spec: str) -> list[int]:
    """The frames of ``--frames``: Blender's ``-f`` list, numbers and inclusive
    ranges ``A..B`` joined by commas (``1,3,5..10``), in the order given,
    each once.  Blender's relative forms (``+N``, ``-N`` from the range's
    ends) are not read: a leading minus is a negative frame."""
    import re
    frames: list[int] = []
    seen = set()
    for part in spec.split(","):
        m = re.fullmatch(r"\s*(-?\d+)\s*(?:\.\.\s*(-?\d+)\s*)?", part)
        if m is None:
            raise CLIError(EXIT_USAGE, f"--frames {spec!r}: '{part}' is not a frame or a range "
                                       f"A..B (e.g. 1,3,5..10).")
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) is not None else a
        if b < a:
            raise CLIError(EXIT_USAGE, f"--frames {spec!r}: the range {a}..{b} runs backwards.")
        for f in (a, b):
            if not FRAME_RANGE[0] <= f <= FRAME_RANGE[1]:
                raise CLIError(EXIT_USAGE, f"--frames {spec!r}: frame {f} is outside "
                                           f"[{FRAME_RANGE[0]}, {FRAME_RANGE[1]}] (Blender's "
                                           f"frame range).")
        for f in range(a, b + 1):
            if f not in seen:
                seen.add(f)
                frames.append(f)
    return frames


def frame_path(path: str, frame: int, always: bool) -> str:
    """The output of ``frame``: the last run of ``#`` in the file name becomes
    the frame number, zero-padded to the run's length (Blender's rule);
    without one, four digits go before the extension when ``always`` (an
    animation), else the path is kept."""
    import re
    d, name = os.path.split(path)
    runs = list(re.finditer(r"#+", name))
    if runs:
        m = runs[-1]
        name = name[:m.start()] + f"{frame:0{m.end() - m.start()}d}" + name[m.end():]
    elif always:
        root, ext = os.path.splitext(name)
        name = f"{root}{frame:04d}{ext}"
    return os.path.join(d, name)


def check_stored(props, overrides: dict) -> None:
    """Refuse an override that ``scene.fppm`` cannot hold as given (Blender would
    clamp it to the property's range, or overflow): exit code 2 naming the range."""
    for name, v in overrides.items():
        back = getattr(props, name)
        same = (abs(back - v) <= 1e-6 * abs(v)) if isinstance(v, float) else back == v
        if not same:
            rna = props.bl_rna.properties[name]
            lo, hi = getattr(rna, "hard_min", None), getattr(rna, "hard_max", None)
            def num(x):
                return f"{x:d}" if isinstance(x, int) else f"{x:g}"
            raise CLIError(EXIT_USAGE, f"{_FLAG_OF.get(name, name)} {v}: must be in "
                                       f"[{num(lo)}, {num(hi)}].")


def render(a) -> int:
    """``fppm render``: returns the exit code; raises CLIError on a documented failure."""
    stop = getattr(a, "stop", None)
    if stop is None:               # called without main (a test): no signal handling
        stop = StopFlag()
    check_input(a.blend)
    # (a '#' in -o stands for the frame: checked again for each frame's name)
    check_output(frame_path(a.output, 0, False), a.blend, a.overwrite, not a.no_preview)
    check_numbers(a)
    a.frame_list = parse_frames(a.frames) if getattr(a, "frames", None) else None
    animation = a.frame_list is not None or getattr(a, "animation", False)
    if animation and a.checkpoint:      # (before check_checkpoint_args makes the folder)
        raise CLIError(EXIT_USAGE, "--checkpoint keeps one frame's render: use it with --frame "
                                   "(an animation continues with --skip-existing).")
    if getattr(a, "skip_existing", False) and not animation:
        raise CLIError(EXIT_USAGE, "--skip-existing needs --frames or --animation.")
    check_checkpoint_args(a)
    overrides = overrides_from_args(a)
    lock = None
    if a.checkpoint:
        from ..core.errors import CheckpointBusy
        from ..core.io import checkpoint
        try:
            lock = checkpoint.lock(a.checkpoint)   # also removes stale temporaries
        except CheckpointBusy as ex:
            raise CLIError(EXIT_CHECKPOINT, str(ex))
        except OSError as ex:
            raise CLIError(EXIT_OUTPUT, f"cannot lock the checkpoint folder '{a.checkpoint}': "
                                        f"{ex.strerror or ex}.")
    try:
        return _render_locked(a, stop, overrides)
    finally:
        if lock is not None:
            lock.release()


def _cancelled_early(stop) -> int:
    _say("Cancelled before the first pass: nothing written.")
    return EXIT_CANCELLED


def _render_locked(a, stop, overrides) -> int:
    if stop:
        return _cancelled_early(stop)

    scene = open_blend(a.blend, a.frame, a.resolution, should_stop=lambda: bool(stop))
    if stop or scene is None:
        return _cancelled_early(stop)
    from .properties import settings_from_scene
    a.file_settings = settings_from_scene(scene)   # before the overrides (read by a.on_renderer)
    if a.frame_list is None and not getattr(a, "animation", False):
        out = frame_path(a.output, scene.frame_current, False)
        if out != a.output:
            check_output(out, a.blend, a.overwrite, not a.no_preview)
        return _render_frame(a, stop, overrides, scene, out)
    return _render_frames(a, stop, overrides, scene)


def _render_frames(a, stop, overrides, scene) -> int:
    """``--frames`` / ``--animation``: each frame in turn in this process (the
    file opened once, the kernels loaded once), into its own EXR.  Stops at
    the first frame that fails or is cancelled, with that frame's exit code;
    the frames written before it stay."""
    # (Blender keeps Frame Start <= End and Step >= 1: never empty)
    frames = a.frame_list if a.frame_list is not None else list(
        range(scene.frame_start, scene.frame_end + 1, scene.frame_step))
    outs = [frame_path(a.output, f, True) for f in frames]   # distinct, as the frames
    written, left_out = 0, 0
    for i, (f, out) in enumerate(zip(frames, outs)):
        if stop:
            break
        if a.skip_existing and os.path.exists(out):
            _say(f"Frame {f}: '{out}' exists: left out (--skip-existing).")
            left_out += 1
            continue
        check_output(out, a.blend, a.overwrite, not a.no_preview)
        scene.frame_set(f)
        _say(f"Frame {f} ({i + 1} of {len(frames)}):")
        try:
            code = _render_frame(a, stop, overrides, scene, out)
        except CLIError as ex:
            raise CLIError(ex.code, f"frame {f}: {ex}" + _frames_kept(written))
        if code != EXIT_OK:
            if code == EXIT_CANCELLED:
                _say(f"Cancelled at frame {f}." + _frames_kept(written))
            return code
        written += 1
    if stop:
        _say("Cancelled between frames." + _frames_kept(written))
        return EXIT_CANCELLED
    _say(f"Animation: {written} frame{'s' * (written != 1)} written"
         + (f", {left_out} left out (already written)" if left_out else "") + ".")
    return EXIT_OK


def _frames_kept(n: int) -> str:
    return (f" The {n} frame{'s' * (n != 1)} written before it {'are' if n != 1 else 'is'} kept."
            if n else "")


def _render_frame(a, stop, overrides, scene, out) -> int:
    """Render the open scene's current frame into ``out`` (EXR and preview)."""
    import bpy

    from . import engine

    progress = Progress(a.quiet)
    ckpt = Checkpointer(a.checkpoint, a.checkpoint_every, _say) if a.checkpoint else None

    def on_pass(pr, st):
        progress(pr, st)
        if ckpt is not None:
            ckpt.after_pass(sess.renderer)

    resume = ckpt.resume if ckpt is not None and a.resume else None
    # a.on_renderer: a caller's hook on the built Renderer (tools/cli.py's
    # --workers / --cluster hand its photon pass to Dask workers there).
    hook = getattr(a, "on_renderer", None)

    def on_renderer(renderer):
        for f in (resume, hook):
            if f is not None:
                f(renderer)

    sess = engine.RenderSession(on_pass=on_pass, log=_say, should_stop=lambda: bool(stop),
                                on_renderer=on_renderer)
    t0 = time.monotonic()
    try:
        render_scene(scene, overrides, sess)
    finally:
        progress.close()
    wall = time.monotonic() - t0
    if sess.result is None or sess.result.pass_index == 0:
        if stop:
            return _cancelled_early(stop)
        raise CLIError(EXIT_INTERNAL, "internal error: the render produced no image.")
    if ckpt is not None:
        ckpt.save(sess.renderer)   # the last complete pass, also on Ctrl-C
    check_image(sess, stop)
    try:
        written = _write_outputs(a, bpy, scene, sess, out, wall)
    except CLIError as ex:
        if ex.code != EXIT_OUTPUT:
            raise
        raise CLIError(EXIT_OUTPUT, str(ex) + _state_kept(ckpt, sess.renderer))
    pr = sess.result
    h, w = pr.image.shape[:2]
    aov = f" + {len(pr.aovs)} AOV{'s' * (len(pr.aovs) != 1)}" if pr.aovs else ""
    _say(f"Done: {w}x{h} px, {pr.stats_line()}, {wall:.1f} s wall"
         f"{' (cancelled)' if stop else ''}.")
    _say(f"Wrote {written[0]} (Combined{aov})"
         + (f" and {written[1]} (view transform '{scene.view_settings.view_transform}')"
            if len(written) > 1 else "") + ".")
    return EXIT_CANCELLED if stop else EXIT_OK


def check_image(sess, stop) -> None:
    """Refuse an image that is not a render: non-finite pixels (exit code 4).

    A black image from a light hidden behind geometry is a correct render
    (Cycles renders it black too): the renderer says so and it is written.
    """
    import numpy as np
    img = np.asarray(sess.result.image)[..., :3]
    bad = ~np.isfinite(img)
    if bad.any():
        raise CLIError(EXIT_SCENE, f"The image has {int(bad.any(axis=-1).sum())} pixel(s) that "
                                   f"are not finite numbers (NaN or infinite): a light, material "
                                   f"or camera value of the scene is out of range; nothing "
                                   f"written.")


def exit_now(code: int) -> None:
    """End the process with ``code`` at once (``os._exit``: no interpreter
    teardown, see ``tools/cli.py`` ``main``), ending the kernel compiler's
    children (``core.warmup.end_children``) and removing Blender's session
    folder first (``bpy.app.tempdir``, ``<temp>/blender_<random>/``): bpy
    removes it itself only at a normal interpreter exit, so every ``fppm``
    command left one behind in the temporary folder."""
    # the kernel compiler's children and their folders (no finalizer runs
    # after os._exit); core.warmup only if this process imported it
    warmup = sys.modules.get(__package__.rsplit(".", 1)[0] + ".core.warmup")
    if warmup is not None:
        try:
            warmup.end_children()
        except Exception:   # noqa: BLE001 - quitting: what is left is swept later
            pass
    bpy = sys.modules.get("bpy")
    try:
        folder = os.path.normpath(bpy.app.tempdir) if bpy is not None else ""
        if os.path.basename(folder).startswith("blender_"):
            import shutil
            shutil.rmtree(folder, ignore_errors=True)
    except Exception:       # noqa: BLE001 - bpy half imported (an early signal): leave it
        pass
    os._exit(code)


class StopFlag:
    """SIGINT (Ctrl-C) and SIGTERM as a flag, never as an exception.

    Installed by :func:`main` before anything else (and by ``tools/cli.py``
    before importing the add-on, which imports bpy): a signal at any instant
    sets the flag, which the CLI checks between its steps and the renderer
    polls inside passes.  Raising KeyboardInterrupt instead could unwind
    through Blender's or numba's C frames (a crash, or a signal swallowed).
    A second signal quits at once with exit code 130, writing nothing.

    early: signals received before this object existed (``tools/cli.py``).
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self, early=()):
        # The same list as the early handler's, so a signal between the two
        # installations is not lost.
        self.received = early if isinstance(early, list) else list(early)
        self._previous = {}

    def __bool__(self) -> bool:
        return bool(self.received)

    def handler(self, signum, frame) -> None:
        self.received.append(signum)
        if len(self.received) >= 2:
            os.write(2, b"fppm: interrupted twice: quitting now, nothing written.\n")
            exit_now(EXIT_CANCELLED)

    def install(self) -> "StopFlag":
        import threading
        if threading.current_thread() is threading.main_thread():
            for sig in self.SIGNALS:
                self._previous[sig] = signal.signal(sig, self.handler)
        return self

    def restore(self, defaults: bool = False) -> None:
        """Put back the handlers found by install() (defaults: Python's own:
        KeyboardInterrupt for SIGINT, the system's for SIGTERM)."""
        if defaults:
            self._previous = {sig: (signal.default_int_handler if sig == signal.SIGINT
                                    else signal.SIG_DFL) for sig in self._previous}
        for sig, h in self._previous.items():
            signal.signal(sig, h if h is not None else signal.SIG_DFL)
        self._previous.clear()


# The sub-commands of this module: {name: (add_parser(sub), run(args) -> exit code)}.
COMMANDS = {"render": (add_render_parser, render)}


def main(argv=None, commands: dict | None = None, early_signals=()) -> int:
    """Parse ``argv`` and run the sub-command; returns the exit code (never raises).

    commands: the sub-commands (default :data:`COMMANDS`); ``tools/cli.py``
    adds the development tools to them.  A run function raises CLIError for
    a documented failure: its message goes to stderr and its code is returned.
    early_signals: SIGINT / SIGTERM received before main (``tools/cli.py``'s
    first instruction installs a handler that records them).
    SIGINT and SIGTERM set ``args.stop`` (:class:`StopFlag`) from here on.
    """
    stop = StopFlag(early_signals).install()
    try:
        commands = COMMANDS if commands is None else commands
        parser = build_parser(commands)
        try:
            a = parser.parse_args(argv)
        except SystemExit as ex:   # argparse: 2 on usage errors, 0 for --help
            return int(ex.code or 0)
        if stop:
            print("fppm: interrupted.", file=sys.stderr, flush=True)
            return EXIT_CANCELLED
        a.stop = stop
        if a.command != "render":
            # Other commands (fppm converge) handle SIGINT themselves; SIGTERM
            # keeps its default (end the process) there.
            stop.restore(defaults=True)
        try:
            return commands[a.command][1](a)
        except CLIError as ex:
            print(f"fppm: error: {ex}", file=sys.stderr, flush=True)
            return ex.code
        except KeyboardInterrupt:
            print("fppm: interrupted.", file=sys.stderr, flush=True)
            return EXIT_CANCELLED
        except Exception:
            traceback.print_exc()
            return EXIT_INTERNAL
    finally:
        stop.restore()


if __name__ == "__main__":
    sys.exit(main())
