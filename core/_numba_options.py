"""Decorator options shared by the compiled kernels (no numba import here).

:data:`NO_REFCOUNTS`: for a compiled helper that another kernel calls once
per element (a pair, a ray, a light sample) and that takes arrays but
creates none: numba's ``_nrt=False`` (private, and used by numba's own
library).  Without it every call takes and drops a reference to each array
argument (calls into numba's runtime, atomic operations): 20-25 ns a call of
``materials.compiled.eval_pair_as``, half of what a Lambert lobe's f costs
(docs/architecture.md "The BSDF evaluation's fixed cost, round 32").  Such a
function must not allocate: there is no runtime to free what it makes.
"""

NO_REFCOUNTS = {"_nrt": False}
