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
