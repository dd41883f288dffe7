"""Stress runs: long soaks, shutdown storms and the two-host link, run by hand when the
node graph changes (they take minutes to hours, some need root)."""
