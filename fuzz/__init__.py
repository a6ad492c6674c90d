"""Fuzzing harnesses for the .atm decoder (see fuzz/README.md)."""
