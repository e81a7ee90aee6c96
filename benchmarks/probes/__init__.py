"""Probes: prototypes measured on flatcli's real loops before anything is built (each
module's docstring says what it measures and how to run it)."""
