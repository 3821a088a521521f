"""Training, evaluation and checkpoints for the embedded model (bpy-free; runs under torchrun)."""
