"""FPPM core: frequency-based progressive photon mapping in numpy + Embree.

Never imports ``bpy``: everything here runs under plain pytest.
"""
__version__ = "0.1.0"
