"""Scene description: the exported model, Cycles node translation, textures, camera."""
