"""Families built from other families: ``fixed`` (curriculum) and ``mixed``."""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from datt.configuration import SEED, WEIGHT, check_arg_ranges
from datt.refs.base import RefFamily


class Seeded(RefFamily):
    """``family`` drawn with its own generator seeded at ``seed`` on every call: the same n
    references come back each time, whatever the env's generator (evaluation banks)."""

    ARG_RANGES = {"seed": SEED}

    def __init__(self, family: RefFamily, seed: int = 0) -> None:
        check_arg_ranges(Seeded, {"seed": seed}, "traj")
        self.family = family
        self.seed = int(seed)

    def sample(self, n: int, t_s: Tensor, generator: torch.Generator) -> Tensor:
        own = torch.Generator(device=t_s.device).manual_seed(self.seed)
        return self.family.sample(n, t_s, own)


class Fixed(Seeded):
    """One reference, drawn once from ``family`` with its own ``seed``, given to every drone.

    Used by the training curriculum (paper §4.1: a fixed initial reference for the first 2.5 M
    steps). The draw does not consume the env's generator, so the reference is the same in
    every run and seed.
    """

    def __init__(self, family: RefFamily, seed: int = 0) -> None:
        super().__init__(family, seed)
        self._cache: dict[tuple, Tensor] = {}

    def sample(self, n: int, t_s: Tensor, generator: torch.Generator) -> Tensor:
        key = (t_s.shape[0], float(t_s[-1]), t_s.dtype, t_s.device)
        if key not in self._cache:
            self._cache[key] = super().sample(1, t_s, generator)
        return self._cache[key].expand(n, -1, -1)


class Mixed(RefFamily):
    """Each drone's family drawn independently with probabilities ∝ ``weights`` (uniform when
    omitted). ``families``: name -> family (Hydra instantiates the nested configs). Mean speed of
    ``traj=mixed`` (authors' zigzag, poly, chained_poly; 1000 draws): ≈ 0.82 m/s."""

    ARG_RANGES = {"weights": WEIGHT}  # per family; their sum must be > 0

    def __init__(self, families: Mapping[str, RefFamily], weights: Mapping[str, float] | None = None) -> None:
        if not families:
            raise ValueError("traj.families: needs at least one family")
        self.names = list(families)
        self.families = [families[k] for k in self.names]
        weights = dict(weights or {})
        unknown = set(weights) - set(self.names)
        if unknown:
            raise ValueError(f"traj.weights: unknown families {sorted(unknown)}; allowed: {self.names}")
        w = torch.tensor([float(weights.get(k, 1.0)) for k in self.names])
        if not torch.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
            raise ValueError("traj.weights: must be >= 0 with a positive sum")
        self.probs = w / w.sum()

    def sample(self, n: int, t_s: Tensor, generator: torch.Generator) -> Tensor:
        probs = self.probs.to(generator.device)  # the draw runs where the env's generator lives (env.device)
        choice = torch.multinomial(probs, n, replacement=True, generator=generator).to(t_s.device)
        out = torch.empty(n, t_s.shape[0], 3, dtype=t_s.dtype, device=t_s.device)
        for k, fam in enumerate(self.families):  # loop over families, not drones
            idx = (choice == k).nonzero().squeeze(-1)
            if len(idx):
                out[idx] = fam.sample(len(idx), t_s, generator)
        return out
