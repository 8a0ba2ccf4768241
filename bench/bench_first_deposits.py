"""Which deposits of a frequency photon set a pixel's predicted radius: the
whole chain against its first k counted deposits (``PhotonTracer.freq_deposits``,
docs/frequency.md "Fewer marched deposits").

    .venv/bin/python bench/bench_first_deposits.py indirect_room [--passes 4 8] [--k 1,2]

The .blend at 50 % (64x64) with the file's settings, photon mapping, 100,000
photons a pass, 25 % frequency photons in every pass (``frequency_decay``
0, no doubling); one FPPM renderer is stepped, and at each of ``--passes``
its photon pass is first run again on the same visible points and radii
with the same stream for k = 0 (every deposit) and each k: per pixel the
smallest predicted radius (the MIN estimator's fold), compared.  Prints,
over the pixels with a prediction under k = 0: the share left without any
under k, the share whose smallest radius is larger under k (a later
deposit set it), the median of that ratio, and the share whose prediction
lies below the pixel's radius (where it can hold it smaller than growth
would) under each.
"""
from __future__ import annotations

import argparse
import os

# bench_hold_alpha first: one numba and one tracing thread, tests/ on the path
# (this script's directory, bench/, is sys.path[0])
from bench_hold_alpha import export  # noqa: E402
from bench_render import PassProxy  # noqa: E402

import numpy as np  # noqa: E402

from fppm.core.render import Renderer  # noqa: E402


class _Compare(PassProxy):
    """Around a PhotonPass: at the chosen passes, the pass run again per k
    on the same visible points and radii and a fresh stream of one seed;
    the per-pixel smallest radii kept."""

    def __init__(self, pp, ks, at, renderer):
        super().__init__(pp, _ks=ks, _at=at, _r=renderer, out={})

    def __call__(self, vp, R2, spectrum, rng, check_stop=lambda: None):
        pp, tr = self._pp, self._pp.tracer
        k_pass = self._r.pass_index + 1
        if k_pass in self._at:
            k0 = tr.freq_deposits
            res = {}
            for k in [0] + self._ks:
                tr.freq_deposits = k
                est = pp(vp, R2, None, np.random.default_rng(1000 + k_pass), check_stop)
                res[k] = np.array(est.r_pred_min, np.float64)
            tr.freq_deposits = k0
            self.out[k_pass] = (res, np.sqrt(np.asarray(R2, np.float64)),
                                vp.valid & (np.asarray(R2) > 0))
        return pp(vp, R2, spectrum, rng, check_stop)


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("scene")
    ap.add_argument("--passes", type=int, nargs="+", default=[4, 8])
    ap.add_argument("--k", default="1,2")
    ap.add_argument("--photons", type=int, default=100_000)
    a = ap.parse_args()
    scene, base = export(a.scene)
    st = base.replace(photons_per_pass=a.photons, frequency_decay=0.0, max_passes=max(a.passes))
    r = Renderer(scene, st, log=lambda s: None)
    r.photon_pass.doubling = False
    ks = [int(x) for x in a.k.split(",")]
    w = _Compare(r.photon_pass, ks, set(a.passes), r)
    r.photon_pass = w
    for _ in range(max(a.passes)):
        r.step()
    print(f"# {a.scene}: {a.photons} photons a pass, 25 % frequency photons in every pass; "
          f"load {os.getloadavg()[0]:.1f}")
    for p, (res, R, act) in sorted(w.out.items()):
        r0 = res[0]
        has0 = act & np.isfinite(r0)
        print(f"pass {p}: pixels with a prediction (k=0) {has0.sum()} of {act.sum()}; "
              f"below the pixel radius {np.mean(r0[has0] < R[has0]):.3f}")
        for k in ks:
            rk = res[k]
            none = ~np.isfinite(rk[has0])
            larger = rk[has0] > r0[has0]
            both = has0 & np.isfinite(rk)
            q = rk[both] / r0[both]
            print(f"  k={k}: none {np.mean(none):.3f}, larger or none {np.mean(larger):.3f} "
                  f"(median ratio where larger {np.median(q[q > 1]) if (q > 1).any() else 1:.2f}), "
                  f"below the pixel radius {np.mean(rk[has0] < R[has0]):.3f}")


if __name__ == "__main__":
    main()
