"""The `atm` command line tool, installed as codec.cli (also `python -m codec`)."""
