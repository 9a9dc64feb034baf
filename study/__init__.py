"""Studies: many runs at once, over worlds, modes and training terms. The layer that composes
generation (datagen) and training (train), which know nothing of each other."""
