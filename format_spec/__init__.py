"""The .atm format: the normative text is ATM.md beside this file; schema.py is the
byte layout as `construct` declarations, the single source of truth the codec reads
and writes with."""
