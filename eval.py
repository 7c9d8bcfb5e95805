"""`python eval.py [overrides]`: thin Hydra shim over :mod:`datt.cli` (see conf/eval.yaml)."""

from datt.cli import eval_main

if __name__ == "__main__":
    eval_main()
