"""The build numba compiles the kernels for, which exact pins depend on.

numba compiles every kernel for the host CPU: LLVM's vector width and FMA
contraction, and libm, change the last bits of a result, and a last bit can
move a photon's path.  Pins kept bit for bit (tests/pin_images.py,
tests/test_photon_trace_pins.py, tests/test_frequency_one_batch.py) are
therefore kept per build (docs/architecture.md "Pinned images on another CPU").
"""


def build_key():
    """{"cpu": numba's target CPU (``NUMBA_CPU_NAME`` or the host's, e.g.
    "znver3"), "numba": its version, "llvmlite": its version}."""
    import llvmlite
    import llvmlite.binding as ll
    import numba
    return {"cpu": numba.config.CPU_NAME or ll.get_host_cpu_name(),
            "numba": numba.__version__, "llvmlite": llvmlite.__version__}


#: The CPU the digests written before per-build pins were made on (not
#: recorded then; not znver3).  Digests under this key are used on any CPU
#: that has none of its own.
EARLIER_CPU = "the machine before (unrecorded)"


def for_this_cpu(by_cpu: dict):
    """The entry of ``by_cpu`` (CPU name -> digests) for this build's CPU, or
    the earlier machine's when this CPU has none (those then fail with the
    test's message to regenerate them on this CPU)."""
    return by_cpu.get(build_key()["cpu"], by_cpu[EARLIER_CPU])
