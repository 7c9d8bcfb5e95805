"""`python train.py [overrides]`: thin Hydra shim over :mod:`datt.cli` (see conf/train.yaml)."""

from datt.cli import train_main

if __name__ == "__main__":
    train_main()
