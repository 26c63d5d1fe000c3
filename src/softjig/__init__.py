"""softjig: the software of a sensing soft jig (Sakuma et al., "Soft-Jig")."""

__version__ = "0.1.0"
