"""Jig design studies: many designs x parts x poses through simulation and estimation (issue 17)."""
