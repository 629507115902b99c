"""Settings of a reconstruction (``python -m reneus_mi.optimize``).

What is rendered (mode, D_re, samples per segment, the field's architecture)
belongs to the scene's ``<integrator type="reneus">``; how it is fitted is
here. Every field's docstring is its command-line help.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass


@dataclass
class TrainConfig:
    iterations: int = 3000
    """Optimisation steps (the paper: 200k on a GPU)."""
    batch_rays: int = 1024
    """Camera rays per step, drawn at random from the container masks of all views."""
    learning_rate: float = 5e-4
    """Peak learning rate of Adam (NeuS)."""
    learning_rate_alpha: float = 0.05
    """Final learning rate as a fraction of the peak, reached by cosine decay (NeuS)."""
    warm_up: int = 100
    """Steps of linear learning-rate warm-up (NeuS: 5000 of 300k)."""
    anneal_end: int = 0
    """Steps over which NeuS's cosine annealing ratio goes from 0 to 1 (0: no annealing)."""
    trans_weight: float = 0.1
    """λ1, weight of the transmittance sparsity prior L_trans (0 disables it)."""
    eikonal_weight: float = 0.1
    """λ2, weight of the Eikonal regulariser L_reg."""
    seed: int = 0
    """Seed of the ray batches and the stratified jitter: a fixed seed gives the same run."""
    validate_every: int = 500
    """Steps between validation renders (image + normal map, PNG) and mesh snapshots (0: never)."""
    validation_view: int = 0
    """Index of the view rendered for validation."""
    checkpoint_every: int = 100
    """Steps between checkpoints (written atomically; --resume continues from the last)."""
    mesh_resolution: int = 256
    """Marching-cubes grid resolution of the final mesh."""
    postprocess: str = 'largest'
    """Mesh post-processing: 'largest' (keep the largest connected component, the paper),
    'crop' (drop what lies outside the container) or 'none'."""
    divergence_factor: float = 50.0
    """Stop when the loss exceeds this multiple of its lowest value so far (after warm-up)."""

    def __post_init__(self):
        for name in ('iterations', 'batch_rays', 'mesh_resolution'):
            if getattr(self, name) < 1:
                raise ValueError(f'{name}={getattr(self, name)}: expected a positive integer')
        for name in ('warm_up', 'anneal_end', 'validate_every', 'checkpoint_every', 'validation_view'):
            if getattr(self, name) < 0:
                raise ValueError(f'{name}={getattr(self, name)}: expected an integer >= 0')
        for name in ('learning_rate', 'divergence_factor'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name}={getattr(self, name)}: expected a positive number')
        for name in ('trans_weight', 'eikonal_weight', 'learning_rate_alpha'):
            if not getattr(self, name) >= 0:
                raise ValueError(f'{name}={getattr(self, name)}: expected a number >= 0')
        if self.postprocess not in ('largest', 'crop', 'none'):
            raise ValueError(f"postprocess={self.postprocess!r}: expected 'largest', 'crop' or 'none'")

    def learning_rate_at(self, it: int) -> float:
        """NeuS's schedule: linear warm-up, then cosine decay to ``learning_rate_alpha``."""
        if it < self.warm_up:
            return self.learning_rate * (it + 1) / self.warm_up
        progress = (it - self.warm_up) / max(self.iterations - self.warm_up, 1)
        a = self.learning_rate_alpha
        return self.learning_rate * ((math.cos(math.pi * progress) + 1.0) * 0.5 * (1 - a) + a)

    def cos_anneal_ratio(self, it: int) -> float:
        return 1.0 if self.anneal_end == 0 else min(1.0, it / self.anneal_end)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)
