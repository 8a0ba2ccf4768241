"""Photon and light-path chunks on Dask workers (``fppm render --workers/--cluster``, tools/distributed.py).

The scene: tests/scenes/t_glossy_floor.blend at 16x16 (a GGX floor: the
non-Lambert pairs), with the Quantile estimator (radius histograms) and the
spectrum AOV (the spectrum a later chunk overwrites), so every sum a chunk
returns is exercised.  One process with one random stream per chunk is the
reference: the workers must give it bit for bit (max abs difference 0).

Integrator COMBINED: tests/scenes/t_glass_caustic.blend at 16x16 (a glass
caustic: light tracing and photon merging both on), 3 passes of 4 chunks of
5,000 light paths and 4 of 5,000 merging photons, against one process with
the same chunk streams, bit for bit.
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
from fppm.core.integrators.light_tracer import SplatSums  # noqa: E402
from fppm.tools import distributed as D  # noqa: E402

needs_dask = pytest.mark.skipif(importlib.util.find_spec("distributed") is None,
                                reason="dask.distributed is not installed")

SCENE = os.path.join(H.ROOT, "tests", "scenes", "t_glossy_floor.blend")
PASSES, PHOTONS, CHUNK, SEED = 3, 40_000, 10_000, 5      # 4 chunks per pass


def _export(blend, tmp_path_factory, photons, **kw):
    """(saved copy, exported core Scene, settings) of blend at 25 % with the
    test's passes and seed, photons per pass and the settings kw."""
    H.ensure_registered()
    from fppm.addon.export import export_scene
    from fppm.addon.properties import settings_from_scene
    bpy.ops.wm.open_mainfile(filepath=blend, load_ui=False, use_scripts=False)
    sc = bpy.context.scene
    sc.render.resolution_percentage = 25
    H.small_settings(sc, PASSES, photons, SEED, **kw)
    path = H.save_blend(tmp_path_factory.mktemp("dist") / os.path.basename(blend))
    scene = export_scene(bpy.context.evaluated_depsgraph_get(), log=lambda s: None)
    return path, scene, settings_from_scene(sc)


@pytest.fixture(scope="module")
def glossy(tmp_path_factory):
    """(saved .blend, exported core Scene, settings) of the small glossy scene."""
    return _export(SCENE, tmp_path_factory, PHOTONS, frequency_estimator="QUANTILE",
                   aov_spectrum=True)


def _renderer(exported, chunk=CHUNK):
    """A one-process renderer of an exported scene with chunk streams."""
    _, scene, st = exported
    return D.local_chunk_streams(Renderer(scene, st, log=lambda s: None), chunk)


@pytest.fixture(scope="module")
def reference(glossy):
    """The one-process render (chunk streams): image and spectrum AOV."""
    r = _renderer(glossy)
    res = r.run()
    # Chunk 0 carries frequency photons (fewer in later passes: frequency_decay).
    n0, f0 = r.photon_pass.chunks()[0]
    assert r.pass_index == PASSES and n0 == CHUNK and f0 > 0
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


def _render_on_2_workers(exported, chunk, out, *flags, client=None):
    """`fppm render --workers 2 --chunk chunk [flags]` of the saved file: (its
    log, the EXR's layers).  client: the module's cluster of 2 workers, which
    the render joins (`--cluster ADDRESS`) instead of starting its own (the
    same workers, one start-up for the module)."""
    where = (("--cluster", client.scheduler.address) if client is not None
             else ("--workers", 2))
    two = H.run_fppm("render", exported[0], "-o", out, *where, "--chunk", chunk,
                     "-q", "--no-preview", *flags)
    assert two.returncode == 0, two.stderr[-2000:]
    return two.stdout + two.stderr, read_exr(str(out))


@pytest.fixture(scope="module")
def client():
    """A local cluster of 2 workers, shared by the killed-worker tests (the
    nanny replaces a killed worker)."""
    c = D.connect(workers=2)
    yield c
    D.close(c)


def _workers_without_bpy(client) -> bool:
    """No worker has imported bpy (the fppm package imports it only to
    register the add-on), so a killed worker leaves no Blender session
    folder (<TMPDIR>/blender_<random>) behind."""
    return not any(client.run(lambda: "bpy" in __import__("sys").modules).values())


@needs_dask
def test_local_workers_do_not_print_the_shutdown_heartbeat(client):
    # Dask's shutdown race: a worker's heartbeat meets the closed scheduler
    # and it logs an ERROR with a traceback after the render has ended.  The
    # local workers drop that one message, and only it.
    import logging

    def probe():
        log = logging.getLogger("distributed.worker")
        lost = log.makeRecord(log.name, logging.ERROR, "worker.py", 0,
                              D.HEARTBEAT_LOST + ".", (), None)
        other = log.makeRecord(log.name, logging.ERROR, "worker.py", 0, "Compute Failed", (), None)
        return bool(log.filter(lost)), bool(log.filter(other))

    client.wait_for_workers(2, timeout=60)
    seen = client.run(probe)
    assert len(seen) == 2 and set(seen.values()) == {(False, True)}


def _kill_holder(client, pids, futures, killed, kept=False):
    """SIGKILL, once, a worker processing one of futures (with kept: or
    keeping its result); its address goes into killed."""
    keys = {f.key for f in futures}
    holders = {w for ws in client.who_has(futures).values() for w in ws} if kept else set()
    for addr, tasks in client.processing().items():
        if (keys & set(tasks) or addr in holders) and addr in pids:
            os.kill(pids[addr], signal.SIGKILL)
            killed.append(addr)
            return


@needs_dask
def test_killed_worker_gives_the_same_image(glossy, reference, client):
    pids = client.run(os.getpid)            # {worker address: pid}
    killed = []
    # On a loaded machine every chunk of pass 2 may come back between two
    # polls: then the render is run again (at most three times).
    for _attempt in range(3):
        r = _renderer(glossy)
        dist = D.DistributedPhotonPass(client, r)

        def kill_one_mid_pass(r=r, dist=dist):
            # Polled while the driver waits for this pass's chunks: kill,
            # once, a worker holding a chunk of pass 2 that has not come back.
            if not killed and r.pass_index == 1 and dist.pending:
                _kill_holder(client, pids, [f for f in dist.pending if not f.done()], killed)
            return False

        res = r.run(should_stop=kill_one_mid_pass)
        dist.close()
        if killed:
            break
    client.wait_for_workers(2, timeout=60)           # the nanny replaced it
    replaced = client.run(os.getpid)
    assert killed, "no chunk of pass 2 was seen on a worker"
    assert pids[killed[0]] not in replaced.values() and len(replaced) == 2
    assert _workers_without_bpy(client)
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


# ----------------------------------------------------------------------------
# Integrator COMBINED: light-path chunks and merging-photon chunks
# ----------------------------------------------------------------------------

CAUSTIC = os.path.join(H.ROOT, "tests", "scenes", "t_glass_caustic.blend")
C_PATHS, C_CHUNK = 20_000, 5_000          # 4 chunks of light paths (and of photons) per pass


@pytest.fixture(scope="module")
def caustic(tmp_path_factory):
    """(saved .blend, exported core Scene, settings) of the glass caustic, COMBINED."""
    return _export(CAUSTIC, tmp_path_factory, C_PATHS, integrator="COMBINED", camera_samples=1,
                   merge_weights="PARTITION")


@pytest.fixture(scope="module")
def combined_reference(caustic):
    """The one-process COMBINED render (chunk streams)."""
    r = _renderer(caustic, C_CHUNK)
    assert r.merging and r.combined_lt is not None      # both light-side stages split
    res = r.run()
    assert r.pass_index == PASSES and r.combined_lt.chunks(C_PATHS) == [C_CHUNK] * 4
    return res


def test_light_chunk_sums_do_not_depend_on_the_order_chunks_are_traced(caustic):
    # What lets any worker trace any chunk of light paths: the chunks of a
    # pass traced last to first (chunk_sums, as workers would) and added in
    # chunk order give the one-process pass exactly.
    lt = _renderer(caustic, C_CHUNK).combined_lt
    rng = np.random.default_rng(np.random.SeedSequence([SEED, 1, 2]))
    film = lt.trace_pass(C_PATHS, rng)
    chunks = list(enumerate(lt.chunks(C_PATHS)))
    parts = {c: lt.chunk_sums(C_PATHS, n, chunk_rng(rng, c)) for c, n in reversed(chunks)}
    acc = np.zeros_like(film)
    for c, _ in chunks:
        parts[c].add_to(acc)
    assert film.sum() > 0 and np.array_equal(acc, film)
    # A chunk that touches few pixels comes back sparse, with the same sums.
    lit = np.flatnonzero(film.any(axis=1))[:2]
    few = np.zeros_like(film)
    few[lit] = film[lit]
    part = SplatSums.sparse(few)
    assert part.idx.tolist() == lit.tolist() and part.nbytes == 2 * (24 + 8)
    again = film.copy()
    part.add_to(again)
    assert np.array_equal(again, film + few)


def test_partition_fallback_is_said_only_when_it_replaces_mis():
    # The workers force PARTITION; the log says so only when the weights in
    # effect (--merge-weights, else the file's) were MIS.
    from argparse import Namespace
    for given, in_file, said in ((None, "PARTITION", False), (None, "MIS", True),
                                 ("partition", "MIS", False), ("mis", "PARTITION", True)):
        a = Namespace(merge_weights=given)
        replaced = D.partition_fallback(a)
        assert a.merge_weights == "partition" and replaced(in_file) is said, (given, in_file)


@needs_dask
def test_combined_workers_2_same_image_as_one_process(caustic, combined_reference, tmp_path,
                                                      client):
    # --merge-weights mis: the workers return no deposits to merge, so the
    # render falls back to the partition, says so, and is the one-process
    # partition render bit for bit.
    log, got = _render_on_2_workers(caustic, C_CHUNK, tmp_path / "two.exr",
                                    "--merge-weights", "mis", client=client)
    assert D.PARTITION_FALLBACK in log
    assert ("Light paths in chunks of 5000 and merging photons in chunks of 5000, one random "
            "stream each, on 2 Dask workers") in log
    assert np.abs(got["Combined"] - combined_reference.image).max() == 0.0


RING = os.path.join(H.ROOT, "example_blends", "ring_lambert.blend")


@needs_dask
def test_workers_2_when_the_holds_are_left_out(tmp_path_factory, tmp_path, client):
    # The ring holds few of its pixels after pass 1, so FPPM renders on as
    # plain PPM (Renderer._drop_holds): the driver's photon pass and then
    # every worker's drop the frequency photons and sector counts.  Before,
    # `--workers` stopped there ('DistributedPhotonPass' has no
    # drop_frequency).  The same image as one process, bit for bit.
    ring = _export(RING, tmp_path_factory, PHOTONS, frequency_estimator="QUANTILE")
    r = _renderer(ring)
    one = r.run()
    assert r.radii.holds_left_out is not None and not r.photon_pass.frequency
    log, got = _render_on_2_workers(ring, CHUNK, tmp_path / "two.exr", client=client)
    assert "on 2 Dask workers" in log
    assert one.image.max() > 0 and np.abs(got["Combined"] - one.image).max() == 0.0


REAL = os.path.join(H.ROOT, "example_blends", "real_scene.blend")


@needs_dask
def test_workers_keep_the_normal_maps(tmp_path_factory, tmp_path, client):
    # A scene with Normal Map inputs: its shading normals are attached to
    # the tri_n array (core.scene.normals), which pickling a Scene did not
    # carry, so the workers' light paths splatted with the unperturbed
    # normals (Light Tracing on real_scene.blend: a largest difference of
    # 1.9 against one process).  Scene.__setstate__ attaches them again.
    import pickle
    from fppm.core.scene import normals
    real = _export(REAL, tmp_path_factory, C_PATHS, integrator="LIGHT")
    scene = real[1]
    assert normals.attached(scene.tri_n) is not None
    copy = pickle.loads(pickle.dumps(scene))
    spec = normals.attached(copy.tri_n)
    assert spec is not None and spec.tri_n is copy.tri_n
    assert spec.inputs == normals.attached(scene.tri_n).inputs
    r = _renderer(real, C_CHUNK)
    one = r.run()
    log, got = _render_on_2_workers(real, C_CHUNK, tmp_path / "two.exr", client=client)
    assert "on 2 Dask workers" in log
    assert one.image.max() > 0 and np.abs(got["Combined"] - one.image).max() == 0.0


CORNELL = os.path.join(H.ROOT, "tests", "scenes", "t_cornell.blend")


@needs_dask
def test_workers_2_march_the_occlusion_grid_built_late(tmp_path_factory, tmp_path, client):
    # FPPM's defaults on a box that occludes: the first frequency photons in
    # pass 2 (frequency_start), the occlusion grid built in pass 1's step
    # (Renderer._occlusion_before).  Each worker builds it when it builds
    # the scene: before, the workers' frequency photons marched no grid
    # (a_occ = 0 past every occluder) and the image differed from pass 3 on.
    box = _export(CORNELL, tmp_path_factory, PHOTONS)
    assert box[2].frequency_start == 2 and box[2].integrator == "PHOTON"
    r = _renderer(box)
    assert r.occ_grid is None and r.scene_plan.occlusion_grid     # left for later
    one = r.run()
    assert r.occ_grid is not None and r.tracer.occlusion == 1
    log, got = _render_on_2_workers(box, CHUNK, tmp_path / "two.exr", client=client)
    assert "on 2 Dask workers" in log
    assert one.image.max() > 0 and np.abs(got["Combined"] - one.image).max() == 0.0


@needs_dask
def test_combined_workers_2_when_the_camera_paths_are_restated(tmp_path_factory, tmp_path,
                                                                 client):
    # A diffuse box: COMBINED's light tracer takes every camera path over
    # (camera depth Auto) and the renderer restates the plan's camera-path
    # line after make_plan.  The workers check the plan as made, not the
    # restated one: `--workers 2` rendered nothing on such scenes before
    # ("the render plan differs"), and now gives the one-process image.
    box = _export(CORNELL, tmp_path_factory, C_PATHS, integrator="COMBINED")
    r = _renderer(box, C_CHUNK)
    assert r.plan.strategies != r.scene_plan.strategies
    assert r.plan.strategies[0].startswith("camera paths: none")
    one = r.run()
    log, got = _render_on_2_workers(box, C_CHUNK, tmp_path / "two.exr", client=client)
    assert "on 2 Dask workers" in log
    assert one.image.max() > 0 and np.abs(got["Combined"] - one.image).max() == 0.0


@needs_dask
def test_workers_2_same_image_as_one_process_frame_by_frame(glossy, reference, tmp_path):
    # `fppm render --workers 2` (a local cluster of 2 processes) against the
    # one-process render of the same file, seed and chunking, bit for bit
    # (the image and the Spectrum AOV).  `--frames` builds a renderer a
    # frame; each hands its photon pass to the same cluster after the last
    # frame's stages let go of their scene (tools/cli.py): every frame is
    # the one-process image (a still scene).
    r = H.run_fppm("render", glossy[0], "-o", tmp_path / "f_#.exr", "--frames", "1..2",
                   "--workers", 2, "--chunk", CHUNK, "-q", "--no-preview")
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.count("on 2 Dask workers") == 2 and "Animation: 2 frames written." in r.stdout
    for f in (1, 2):
        got = read_exr(str(tmp_path / f"f_{f}.exr"))
        assert set(got) == {"Combined", "Spectrum"}
        assert np.abs(got["Combined"] - reference.image).max() == 0.0
        assert np.abs(got["Spectrum"] - reference.aovs["Spectrum"]).max() == 0.0


@needs_dask
def test_combined_killed_worker_gives_the_same_image(caustic, combined_reference, client):
    # A worker holding (tracing or keeping) a light chunk of pass 2 is
    # killed: Dask traces that chunk again elsewhere, with the same stream.
    # (With prefetch pass 2's light chunks exist from the end of pass 1's
    # light tracing on: the kill cannot miss them.)
    client.wait_for_workers(2, timeout=60)
    pids = client.run(os.getpid)            # {worker address: pid}
    r = _renderer(caustic, C_CHUNK)
    light, photons = D.distribute(client, r, prefetch=True)
    killed = []

    def kill_one_in_pass_2():
        # Polled between passes and during the stages: pass 2's light
        # chunks are submitted as pass 1's come back (in_flight).
        if not killed and r.pass_index == 1:
            _kill_holder(client, pids, light.in_flight(), killed, kept=True)
        return False

    res = r.run(should_stop=kill_one_in_pass_2)
    light.close()
    photons.close()
    light.session.release()
    client.wait_for_workers(2, timeout=60)           # the nanny replaced it
    replaced = client.run(os.getpid)
    assert killed, "no light chunk of pass 2 was seen on a worker"
    assert pids[killed[0]] not in replaced.values()
    assert r.pass_index == PASSES
    assert np.abs(res.image - combined_reference.image).max() == 0.0
