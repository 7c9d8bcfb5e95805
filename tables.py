"""`python tables.py <table> [overrides]`: thin Hydra shim over :mod:`datt.cli` (see conf/tables.yaml)."""

from datt.cli import tables_main

if __name__ == "__main__":
    tables_main()
