"""The `atm` command line tool (also `python -m cli`)."""
