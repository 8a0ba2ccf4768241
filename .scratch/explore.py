import sys, math, numpy as np
sys.path.insert(0, "/tmp/wt-14a/tests")
import bpy_helpers as H
import bpy
from fppm.addon import engine as E
from test_addon_engine import render, render_result
import pathlib, tempfile
tmp = pathlib.Path(tempfile.mkdtemp())
sc = H.empty_scene((40, 32))
grey = H.node_material("Grey", "BSDF_DIFFUSE", Color=(0.8, 0.8, 0.8, 1.0))
red = H.node_material("Red", "BSDF_DIFFUSE", Color=(0.8, 0.1, 0.1, 1.0))
em = H.node_material("Em", "EMISSION", Color=(1.0, 0.5, 0.2, 1.0), Strength=3.0)
grey.pass_index = 3; red.pass_index = 7; em.pass_index = 9
H.add_plane(sc, material=grey, size=3.0)
cube = H.add_cube(sc, material=red); cube.pass_index = 5
e = H.add_cube(sc, name="E", size=0.4, location=(-1.0, 0.5, 0.4), material=em); e.pass_index = 2
H.add_light(sc, "POINT", 200.0, (1.0, -1.0, 3.0))
H.set_world(sc, (0.05, 0.05, 0.08))
cam = H.add_camera(sc)
sc.render.film_transparent = True
vl = sc.view_layers[0]
for k in ("use_pass_z", "use_pass_mist", "use_pass_normal", "use_pass_object_index", "use_pass_material_index", "use_pass_emit"):
    setattr(vl, k, True)
vl.cycles.denoising_store_passes = True
sc.world.mist_settings.start = 2.0; sc.world.mist_settings.depth = 6.0
H.small_settings(sc, passes=16, photons=20000, seed=1)
sess = render(sc)
print("err", sess.error, getattr(sess, "report", None))
f = render_result(sc, tmp, multilayer=True)
print({k: v.shape for k, v in f.items()})
np.savez(tmp / "fppm.npz", **{k.replace(" ", "_"): v for k, v in f.items()})
sc.render.engine = 'CYCLES'
sc.cycles.samples = 256; sc.cycles.use_denoising = False; sc.cycles.device = 'CPU'
bpy.ops.render.render()
g = render_result(sc, tmp, multilayer=True)
print({k: v.shape for k, v in g.items()})
for k in f:
    if k in g:
        a, b = f[k], g[k]
        print(k, "fppm mean", a.reshape(-1, a.shape[-1]).mean(0) if a.ndim==3 else a.mean(), "cyc", b.reshape(-1, b.shape[-1]).mean(0) if b.ndim==3 else b.mean())
np.savez(tmp / "cyc.npz", **{k.replace(" ", "_"): v for k, v in g.items()})
print(tmp)
