"""The pinned images' comparison across builds (tests/pin_images.py): last-bit
differences of another CPU pass, a change of behaviour of the size the pins
have caught does not.  No rendering: arrays shaped like a 32x32 pin."""
import numpy as np

import pin_images as P


def _pin(rng):
    return {"image": rng.uniform(0.0, 2.0, (32, 32, 4)).astype(np.float32),
            "aov_FPPM Radius": rng.uniform(0.01, 0.05, (32, 32)).astype(np.float32),
            "aov_Photon Count": rng.poisson(290.0, (32, 32)).astype(np.float32)}


def test_last_bits_of_another_build_pass():
    rng = np.random.default_rng(0)
    want = _pin(rng)
    got = {}
    for k, v in want.items():
        x = v.copy()
        m = rng.random(x.shape) < 0.10          # 10 % of the values, as measured between two CPUs
        x[m] = np.nextafter(x[m], np.float32(np.inf))
        got[k] = x
    # one photon (weight 0.9) gathered in one pixel more: the largest difference
    # measured across builds (the Cornell pin's Photon Count, mean 287)
    got["aov_Photon Count"] = want["aov_Photon Count"].copy()
    got["aov_Photon Count"][3, 4] += 0.9
    assert P.differences(got, want)              # not bit-identical ...
    assert P.rel_mse_lines(got, want) == []      # ... but within the bound across builds


def test_a_change_of_behaviour_is_caught_across_builds():
    rng = np.random.default_rng(1)
    want = _pin(rng)
    got = {k: v.copy() for k, v in want.items()}
    # the smallest intended change the pins recorded: 15 of 1,024 radii moved by
    # a rule, ~3 % each (relMSE ~1e-5 of that AOV)
    idx = rng.choice(1024, 15, replace=False)
    got["aov_FPPM Radius"].reshape(-1)[idx] *= 1.03
    lines = P.rel_mse_lines(got, want)
    assert len(lines) == 1 and lines[0].startswith("aov_FPPM Radius: relMSE")
    e = float(lines[0].split("relMSE ")[1].split()[0])
    assert 1e-6 < e < 1e-4


def test_missing_arrays_and_nans_are_reported():
    rng = np.random.default_rng(2)
    want = _pin(rng)
    got = {k: v.copy() for k, v in want.items() if k != "image"}
    assert P.rel_mse_lines(got, want) == ["image: missing from the render"]
    got["image"] = want["image"].copy()
    got["image"][0, 0, 0] = np.nan
    assert P.rel_mse_lines(got, want)[0].startswith("image: shape or NaNs differ")


def test_build_key_names_the_cpu_and_the_compiler():
    k = P.build_key()
    assert set(k) == {"cpu", "numba", "llvmlite"} and all(isinstance(v, str) and v for v in k.values())


def test_digests_are_read_for_this_cpu_or_the_earlier_machine():
    import builds
    here = builds.build_key()["cpu"]
    assert builds.for_this_cpu({builds.EARLIER_CPU: "old", here: "mine"}) == "mine"
    assert builds.for_this_cpu({builds.EARLIER_CPU: "old", "another-cpu": "x"}) == "old"
