"""User-facing errors.  Every message is one clear sentence a Blender user can act on."""


class FPPMError(Exception):
    """Base class: the render cannot proceed; the message says why and what to change."""


class SceneError(FPPMError):
    """The scene cannot be rendered (no lights, nothing visible, no camera, ...)."""


class MemoryBudgetError(FPPMError):
    """The render would not fit in memory; the message names the setting to change."""


class RenderCancelled(FPPMError):
    """Raised inside a pass when the caller's should_stop() turns true."""


class CheckpointMismatch(FPPMError):
    """A checkpoint from another scene or other settings was given to --resume."""


class CheckpointBusy(FPPMError):
    """The checkpoint folder is locked by another render that is still running."""
