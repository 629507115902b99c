"""Fitting the field to photographs: the trainer, its losses and batches, checkpoints, runs."""
