"""Statistics shared by the sampler tests (no scipy: it is not a dependency)."""
import math


def chi2_sf(x, dof):
    """P(X > x) for X ~ chi2(dof): regularised upper incomplete gamma Q(dof/2, x/2)
    (series for x < a + 1, Lentz continued fraction otherwise)."""
    a, x = 0.5 * dof, 0.5 * x
    if x <= 0:
        return 1.0
    lg = a * math.log(x) - x - math.lgamma(a)
    if x < a + 1:
        term = total = 1.0 / a
        ap = a
        for _ in range(10000):
            ap += 1
            term *= x / ap
            total += term
            if abs(term) < abs(total) * 1e-15:
                break
        return max(0.0, 1.0 - total * math.exp(lg))
    b = x + 1 - a
    c = 1e300
    d = 1 / b
    h = d
    for i in range(1, 10000):
        an = -i * (i - a)
        b += 2
        d = an * d + b
        d = 1e-300 if abs(d) < 1e-300 else d
        c = b + an / c
        c = 1e-300 if abs(c) < 1e-300 else c
        d = 1 / d
        h *= d * c
        if abs(d * c - 1) < 1e-15:
            break
    return math.exp(lg) * h


# --- image comparisons against a reference (Cycles or a closed form) --------
def emitter_free_mask(ref):
    """(H, W) bool: pixels farther than 2 px from a pixel brighter than 4x the
    90th percentile of ref (H, W, 3).  Pixels that see an emitter directly are
    left out of image means: their anti-aliased edge (the pixel filter spans
    +-1.5 px) dominates the noise."""
    import numpy as np
    lum = ref.mean(axis=2)
    bright = lum > 4.0 * np.percentile(lum, 90)
    near = bright.copy()
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            near |= np.roll(np.roll(bright, dy, axis=0), dx, axis=1)
    return ~near


def two_seed_relmse_noise(a1, a2, denom):
    """relMSE noise of the mean of two independent renders a1, a2 (H, W, 3):
    per pixel (a1 - a2)^2 / 4 over denom (H, W, 3)."""
    import numpy as np
    return float(np.mean((a1 - a2) ** 2 / 4.0 / denom))


def two_seed_block_sigma(a1, a2, mask):
    """Standard deviation of the masked image mean of (a1 + a2) / 2 (64x64 px),
    from batch means over 8x8-pixel blocks: blocks are far wider than a ~2 px
    kernel, so block means are nearly independent even where pixels share
    photons."""
    import numpy as np
    d = ((a1 - a2).mean(axis=2) * mask).reshape(8, 8, 8, 8).sum(axis=(1, 3))
    return float(np.sqrt(np.sum(d ** 2 / 4.0)) / mask.sum())
