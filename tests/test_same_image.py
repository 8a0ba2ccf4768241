"""The same seed gives the same image, bit for bit, as the pinned renders
(within rounding, tests/pin_images.py ACROSS_BUILDS_REL_MSE, when the pins
were made on another CPU or numba build).

One small render per feature (tests/pin_images.py, VARIANTS): the frequency
kernel with every AOV and the edge cap on (cornell), plain PPM (cornell),
specular chains through glass (glass_sphere), the edge cap off
(point_caustic), the paper's frequency model (coffee_cup).  Film and AOVs
must equal tests/references/pinned/*.npz byte for byte: any change of
behaviour, however small, shows up here, while a refactor that keeps the
behaviour passes.
"""
import pytest

pytest.importorskip("bpy")

import pin_images as P  # noqa: E402

HOW_TO_UPDATE = (
    "The pins are exact only on the CPU and numba/llvmlite build recorded in "
    "tests/references/pinned/made_on.json; on another build the bound is "
    "pin_images.ACROSS_BUILDS_REL_MSE. "
    "If this change of behaviour is intended, regenerate the pins with\n"
    "    .venv/bin/python tests/pin_images.py --update\n"
    "and commit tests/references/pinned/*.npz with the change.")


@pytest.fixture(scope="module")
def renders():
    return P.render_variants(P.NAMES)


@pytest.mark.parametrize("name", P.NAMES)
def test_same_image_as_pinned(renders, name):
    diff = P.check(renders[name], name)
    assert not diff, (f"{name} is no longer the same image as its pin "
                      f"(seed {P.SEED}, {P.PASSES} passes of {P.PHOTONS_PER_PASS} photons):\n  "
                      + "\n  ".join(diff) + "\n" + HOW_TO_UPDATE)
