"""core.io.exr and core.io.atomic: multi-layer EXR round trip, channel layout, atomic writes, clear errors."""
import os
import stat

import numpy as np
import pytest

from core.io.exr import read_exr, read_exr_metadata, write_exr


def _layers(h=5, w=7, seed=0):
    rng = np.random.default_rng(seed)
    return {
        "Combined": rng.random((h, w, 4), dtype=np.float32) * 100,
        "FPPM Radius": rng.random((h, w, 1), dtype=np.float32),
        "Spectrum": rng.standard_normal((h, w, 3)).astype(np.float32),
    }


def test_round_trip_is_bit_exact(tmp_path):
    # float32 channels are stored as FLOAT (not HALF) and ZIP is lossless:
    # the read-back must equal the input bit for bit, including negatives.
    L = _layers()
    p = tmp_path / "a.exr"
    write_exr(str(p), L, {"fppm:seed": "3", "fppm:note": "é ok"})
    R = read_exr(str(p))
    assert set(R) == set(L)
    for k in L:
        assert R[k].dtype == np.float32 and R[k].shape == L[k].shape
        assert np.array_equal(R[k], L[k]), k
    meta = read_exr_metadata(str(p))
    assert meta["fppm:seed"] == "3" and meta["fppm:note"] == "é ok"


def test_channel_names_and_row_order(tmp_path):
    import OpenEXR
    h, w = 4, 3
    img = np.zeros((h, w, 4), np.float32)
    img[0, :, 0] = 1.0          # top row red
    aov = np.arange(h * w, dtype=np.float32).reshape(h, w, 1)
    p = tmp_path / "b.exr"
    write_exr(str(p), {"Combined": img, "Photon Count": aov}, {})
    with OpenEXR.File(str(p), separate_channels=True) as f:
        ch = f.channels()
        assert set(ch) == {"R", "G", "B", "A", "Photon Count.X"}
        # EXR rows run top to bottom: row 0 of the array is the first scanline.
        assert np.array_equal(ch["R"].pixels[0], np.ones(w, np.float32))
        assert np.array_equal(ch["Photon Count.X"].pixels, aov[:, :, 0])


def test_rgb_combined_gets_opaque_alpha(tmp_path):
    p = tmp_path / "c.exr"
    write_exr(str(p), {"Combined": np.full((2, 2, 3), 0.5, np.float32)}, {})
    c = read_exr(str(p))["Combined"]
    assert c.shape == (2, 2, 4) and np.all(c[..., 3] == 1.0) and np.all(c[..., :3] == 0.5)


def test_atomic_replace_leaves_no_temporary(tmp_path):
    p = tmp_path / "d.exr"
    write_exr(str(p), _layers(seed=1), {})
    write_exr(str(p), _layers(seed=2), {})
    assert np.array_equal(read_exr(str(p))["Combined"], _layers(seed=2)["Combined"])
    assert sorted(os.listdir(tmp_path)) == ["d.exr"]
    # The file gets the usual permissions (umask), not mkstemp's 0600.
    mode = stat.S_IMODE(os.stat(p).st_mode)
    mask = os.umask(0)
    os.umask(mask)
    assert mode == 0o666 & ~mask


def test_failed_write_keeps_old_file(tmp_path):
    p = tmp_path / "e.exr"
    write_exr(str(p), _layers(seed=1), {})
    with pytest.raises(ValueError):
        write_exr(str(p), {"Combined": np.zeros((2, 2, 4), np.float32),
                           "Bad": np.zeros((3, 3, 1), np.float32)}, {})
    assert np.array_equal(read_exr(str(p))["Combined"], _layers(seed=1)["Combined"])
    assert sorted(os.listdir(tmp_path)) == ["e.exr"]


def test_missing_folder_is_a_clear_oserror(tmp_path):
    with pytest.raises(OSError, match="does not exist"):
        write_exr(str(tmp_path / "nope" / "x.exr"), _layers(), {})


def test_read_only_folder_is_a_clear_oserror(tmp_path, monkeypatch):
    # Tests run as root in CI, where chmod cannot make a folder unwritable:
    # os.access is what write_exr consults, so it stands in for the folder.
    import core.io.exr as io
    monkeypatch.setattr(io.os, "access", lambda path, mode: False)
    with pytest.raises(OSError, match="not writable"):
        write_exr(str(tmp_path / "x.exr"), _layers(), {})
    assert os.listdir(tmp_path) == []


def test_bad_layers_rejected(tmp_path):
    with pytest.raises(ValueError, match="must not contain"):
        write_exr(str(tmp_path / "f.exr"), {"a.b": np.zeros((2, 2, 1), np.float32)}, {})
    with pytest.raises(ValueError, match="C in 1..4"):
        write_exr(str(tmp_path / "f.exr"), {"x": np.zeros((2, 2, 5), np.float32)}, {})


def test_replace_atomically_keeps_the_old_file_on_failure(tmp_path):
    from core.io.atomic import replace_atomically
    p = tmp_path / "g.bin"
    p.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with replace_atomically(str(p)) as tmp:
            with open(tmp, "wb") as fh:
                fh.write(b"half")
            raise RuntimeError("writer failed")
    assert p.read_bytes() == b"old" and os.listdir(tmp_path) == ["g.bin"]
    with replace_atomically(str(p), mode=0o640) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(b"new")
    assert p.read_bytes() == b"new" and os.listdir(tmp_path) == ["g.bin"]
    assert stat.S_IMODE(os.stat(p).st_mode) == 0o640
