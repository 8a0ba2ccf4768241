"""Photon chunks on Dask workers (``fppm render --workers/--cluster``, tools/distributed.py).

The scene: tests/scenes/t_glossy_floor.blend at 16x16 (a GGX floor: the
non-Lambert pairs), with the Quantile estimator (radius histograms) and the
spectrum AOV (the spectrum a later chunk overwrites), so every sum a chunk
returns is exercised.  One process with one random stream per chunk is the
reference: the workers must give it bit for bit (max abs difference 0).
"""
import importlib.util
import os
import signal

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import bpy_helpers as H  # noqa: E402

from fppm.core.io.exr import read_exr  # noqa: E402
from fppm.core.render import Renderer  # noqa: E402
from fppm.core.sppm.photon_pass import PassSums, chunk_rng  # noqa: E402
from fppm.tools import distributed as D  # noqa: E402

needs_dask = pytest.mark.skipif(importlib.util.find_spec("distributed") is None,
                                reason="dask.distributed is not installed")

SCENE = os.path.join(H.ROOT, "tests", "scenes", "t_glossy_floor.blend")
PASSES, PHOTONS, CHUNK, SEED = 3, 40_000, 10_000, 5      # 4 chunks per pass


@pytest.fixture(scope="module")
def glossy(tmp_path_factory):
    """(saved .blend, exported core Scene, settings) of the small glossy scene."""
    H.ensure_registered()
    from fppm.addon.export import export_scene
    from fppm.addon.properties import settings_from_scene
    bpy.ops.wm.open_mainfile(filepath=SCENE, load_ui=False, use_scripts=False)
    sc = bpy.context.scene
    sc.render.resolution_percentage = 25
    H.small_settings(sc, PASSES, PHOTONS, SEED, frequency_estimator="QUANTILE",
                     aov_spectrum=True)
    path = H.save_blend(tmp_path_factory.mktemp("dist") / "glossy.blend")
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    return path, scene, settings_from_scene(sc)


def _renderer(glossy):
    _, scene, st = glossy
    return D.local_chunk_streams(Renderer(scene, st, log=lambda s: None), CHUNK)


@pytest.fixture(scope="module")
def reference(glossy):
    """The one-process render (chunk streams): image and spectrum AOV."""
    r = _renderer(glossy)
    res = r.run()
    assert r.pass_index == PASSES and r.photon_pass.chunks()[0] == (CHUNK, CHUNK)
    return res


def test_chunk_sums_do_not_depend_on_the_order_chunks_are_traced(glossy):
    # What lets any worker trace any chunk: each pass's chunks traced last to
    # first (chunk_sums, as a worker would) and added in chunk order give the
    # one-process estimate exactly.
    r = _renderer(glossy)
    pp = r.photon_pass
    compared = []

    def both_orders(vp, R2, spectrum, rng, check_stop=lambda: None):
        est = pp(vp, R2, spectrum, rng, check_stop)
        pg = pp.begin(vp, R2, spectrum is not None)
        chunks = list(enumerate(pp.chunks()))
        parts = {c: pp.chunk_sums(pg, n, n_freq, chunk_rng(rng, c))
                 for c, (n, n_freq) in reversed(chunks)}
        acc = PassSums.zeros(vp.valid.shape[0], pp.radius_histogram is not None, spectrum)
        for c, _ in chunks:
            acc.add(parts[c])
        again = pp.finish(vp, acc)
        for name in ("M", "Phi", "r_pred_min", "r_hist", "spectrum"):
            assert np.array_equal(getattr(est, name), getattr(again, name)), name
        compared.append(len(chunks))
        return est

    both_orders.rays = 0
    r.photon_pass = both_orders
    for _ in range(2):
        r.step()
    assert compared == [PHOTONS // CHUNK] * 2


@needs_dask
def test_workers_2_same_image_as_one_process(glossy, reference, tmp_path):
    # `fppm render --workers 2` (a local cluster of 2 processes) against the
    # one-process render of the same file, seed and chunking.
    out = tmp_path / "two.exr"
    two = H.run_fppm("render", glossy[0], "-o", out, "--workers", 2, "--chunk", CHUNK,
                     "-q", "--no-preview")
    assert two.returncode == 0, two.stderr[-2000:]
    assert "on 2 Dask workers" in two.stdout + two.stderr
    got = read_exr(str(out))
    assert set(got) == {"Combined", "Spectrum"}
    assert np.abs(got["Combined"] - reference.image).max() == 0.0
    assert np.abs(got["Spectrum"] - reference.aovs["Spectrum"]).max() == 0.0


@needs_dask
def test_killed_worker_gives_the_same_image(glossy, reference):
    client = D.connect(workers=2)
    try:
        pids = client.run(os.getpid)            # {worker address: pid}
        r = _renderer(glossy)
        dist = D.DistributedPhotonPass(client, r)
        killed = []

        def kill_one_mid_pass():
            # Polled while the driver waits for this pass's chunks: kill, once,
            # a worker holding a chunk of pass 2 that has not come back.
            if killed or r.pass_index != 1 or not dist.pending:
                return False
            keys = {f.key for f in dist.pending if not f.done()}
            for addr, tasks in client.processing().items():
                if keys & set(tasks) and addr in pids:
                    os.kill(pids[addr], signal.SIGKILL)
                    killed.append(addr)
                    break
            return False

        res = r.run(should_stop=kill_one_mid_pass)
        client.wait_for_workers(2, timeout=60)           # the nanny replaced it
        replaced = client.run(os.getpid)
    finally:
        D.close(client)
    assert killed, "no chunk of pass 2 was seen on a worker"
    assert pids[killed[0]] not in replaced.values() and len(replaced) == 2
    assert r.pass_index == PASSES
    assert np.abs(res.image - reference.image).max() == 0.0
    assert np.abs(res.aovs["Spectrum"] - reference.aovs["Spectrum"]).max() == 0.0


@needs_dask
@pytest.mark.parametrize("flags, needs", [
    (["--workers", "0"], "must be at least 1"),
    (["--workers", "2", "--cluster", "tcp://127.0.0.1:1"], "exclude each other"),
    (["--chunk", "0"], "must be at least 1 photon"),
    (["--workers", "2"], "need Dask"),
])
def test_usage_errors(glossy, tmp_path, monkeypatch, capsys, flags, needs):
    from fppm.tools import cli
    monkeypatch.setitem(__import__("sys").modules, "distributed", None)   # Dask not installed
    rc = cli.main(["render", glossy[0], "-o", str(tmp_path / "x.exr"), *flags],
                  exit_process=False)
    assert rc == 2
    assert needs in capsys.readouterr().err
    assert not os.path.exists(tmp_path / "x.exr")
