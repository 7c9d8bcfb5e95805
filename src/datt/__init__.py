"""datt: deep adaptive trajectory tracking for quadrotors (CoRL 2023) on TorchRL."""

__version__ = "0.1.0"
