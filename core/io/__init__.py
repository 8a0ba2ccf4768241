"""Files: EXR images, checkpoints, atomic writes."""
