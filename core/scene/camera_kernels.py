"""Compiled primary rays of :meth:`core.scene.camera.CameraModel.generate`
(pinhole and orthographic), and ``fma``, the once-rounded multiply-add that
lets numba kernels repeat a numpy matrix product's bits.

A module of its own so that importing :mod:`core.scene.camera` (the add-on
does, at register) does not load numba.
"""
from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, prange
from numba.core import types
from numba.extending import intrinsic


@intrinsic
def fma(typingctx, a, b, c):
    """a * b + c rounded once (LLVM's llvm.fma.f64), what OpenBLAS's dgemm
    kernels compute on every x86-64 with FMA (Haswell and later); for
    numba kernels that repeat a numpy matrix product's bits (also
    core.sppm.update)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        f64 = ir.DoubleType()
        fn = builder.module.declare_intrinsic("llvm.fma", [f64], ir.FunctionType(f64, [f64] * 3))
        return builder.call(fn, args)
    return sig, codegen


@njit(cache=True, inline="always")
def _filter_offset(table, u):
    """FilterSampler.sample of one uniform u (the same operations)."""
    n = table.shape[0]
    idx = u * (n - 1)
    i0 = min(np.int64(idx), n - 2)
    f = idx - i0
    return (1.0 - f) * table[i0] + f * table[i0 + 1]


@njit(cache=True)
def _pinhole_range(k0, k1, px, py, uf, table, view, R, origin, ortho, o, d, tmax, dz):
    """Rays k0..k1-1 of :meth:`CameraModel.generate` without a thin lens:
    view = (xmin, ymin, pix, ycor, clip_start, clip_end)."""
    xmin, ymin, pix, ycor, c0, c1 = view[0], view[1], view[2], view[3], view[4], view[5]
    for k in range(k0, k1):
        ox = _filter_offset(table, uf[k, 0])
        oy = _filter_offset(table, uf[k, 1])
        xs = xmin + (px[k] + 0.5 + ox) * pix
        ys = ymin + (py[k] + 0.5 + oy) * ycor * pix
        if ortho:
            cx, cy, cz = 0.0, 0.0, -1.0
        else:
            nrm = np.sqrt(xs * xs + ys * ys + 1.0)
            cx, cy, cz = xs / nrm, ys / nrm, -1.0 / nrm
        t0 = c0 / max(-cz, 1e-12)
        t1 = c1 / max(-cz, 1e-12)
        for j in range(3):
            dw = fma(cz, R[j, 2], fma(cy, R[j, 1], cx * R[j, 0]))
            ow = origin[j]
            if ortho:
                ow = fma(0.0, R[j, 2], fma(ys, R[j, 1], xs * R[j, 0])) + origin[j]
            d[k, j] = dw
            o[k, j] = ow + dw * t0
        tmax[k] = t1 - t0
        dz[k] = cz


@njit(cache=True, parallel=True)
def _pinhole_parallel(n_chunks, px, py, uf, table, view, R, origin, ortho, o, d, tmax, dz):
    K = px.shape[0]
    for c in prange(n_chunks):
        _pinhole_range(c * K // n_chunks, (c + 1) * K // n_chunks, px, py, uf, table, view, R,
                       origin, ortho, o, d, tmax, dz)
