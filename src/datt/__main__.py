"""``python -m datt <command> [overrides]`` = the ``datt`` console script."""

from datt.cli import main

if __name__ == "__main__":
    main()
