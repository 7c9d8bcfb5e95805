"""`python deploy.py [overrides]`: thin Hydra shim over :mod:`datt.cli` (see conf/deploy.yaml)."""

from datt.cli import deploy_main

if __name__ == "__main__":
    deploy_main()
