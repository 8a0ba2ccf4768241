"""FPPM: frequency-based kernel estimation for progressive photon mapping.

This file makes the repository root a Blender extension (it sits beside
``blender_manifest.toml``).  Inside Blender the package is imported as
``bl_ext.<repository>.fppm``; from Python (CLI, tests) as ``fppm``.  ``bpy`` is
imported only inside :func:`register` / :func:`unregister`, so ``core`` stays
importable without Blender.
"""


def register():
    from .addon import register as _register
    _register()


def unregister():
    from .addon import unregister as _unregister
    _unregister()
