"""`python fit_rma.py [overrides]`: thin Hydra shim over :mod:`datt.cli` (see conf/fit_rma.yaml)."""

from datt.cli import fit_rma_main

if __name__ == "__main__":
    fit_rma_main()
