"""One module per task, each a function ``cfg -> metrics`` (the entry points in :mod:`datt.cli`
wrap them in Hydra and report errors)."""
